import pytest
import torch

from prismstereo.errors import (
    OptionError,
    PrismStereoError,
    RigError,
    ShapeError,
    check_floating,
    check_int,
    check_number,
    check_option,
    check_shape,
)


def test_family():
    for exc in (RigError, ShapeError, OptionError):
        assert issubclass(exc, PrismStereoError)
        assert issubclass(exc, ValueError)


@pytest.mark.parametrize(
    "shape,spec",
    [((4, 2), ["*", 2]), ((2,), ["*", 2]), ((3, 5, 2), ["*", "N", 2]), ((1, 3, 4, 5), ["B", "C", "H", "W"])],
)
def test_check_shape_accepts(shape, spec):
    check_shape(torch.zeros(shape), spec, "x")


@pytest.mark.parametrize(
    "shape,spec",
    [((4, 3), ["*", 2]), ((), ["*", 2]), ((3, 2), ["B", "C", "H", "W"]), ((2, 2, 2), [2, 2])],
)
def test_check_shape_rejects(shape, spec):
    with pytest.raises(ShapeError, match=r"x must have shape"):
        check_shape(torch.zeros(shape), spec, "x")


def test_check_shape_not_a_tensor():
    with pytest.raises(ShapeError, match="must be a torch.Tensor"):
        check_shape([1.0, 2.0], ["*", 2], "uv")


def test_check_option():
    assert check_option("left", ("left", "right"), "half") == "left"
    with pytest.raises(OptionError, match=r"Unknown half 'middle'. Choose from: 'left', 'right'"):
        check_option("middle", ("left", "right"), "half")


def test_check_floating():
    check_floating(torch.zeros(2), "x")
    with pytest.raises(PrismStereoError, match="floating-point"):
        check_floating(torch.zeros(2, dtype=torch.int64), "x")
    with pytest.raises(TypeError):
        check_floating(torch.zeros(2, dtype=torch.int64), "x")


def test_top_level_exports_the_depth_model_lazily():
    import prismstereo
    from prismstereo.classical.model import PrismStereo
    from prismstereo.depth.result import DepthResult
    from prismstereo.stream import DepthStream

    assert prismstereo.PrismStereo is PrismStereo and prismstereo.DepthResult is DepthResult
    assert prismstereo.DepthStream is DepthStream
    assert {"PrismStereo", "DepthResult", "DepthStream"} <= set(prismstereo.__all__)
    with pytest.raises(AttributeError, match="has no attribute 'Nope'"):
        prismstereo.Nope  # noqa: B018


def test_check_int():
    assert check_int(3, "band", 1) == 3 and check_int(None, "band", 1, none=True) is None
    for bad in (0, 2.0, True, None):
        with pytest.raises(OptionError, match=r"band must be an int >= 1, got"):
            check_int(bad, "band", 1)
    with pytest.raises(OptionError, match=r"band must be an int >= 1 or None, got 0"):
        check_int(0, "band", 1, none=True)


def test_check_number():
    assert check_number(0.5, "c", 0.0, 1.0) == 0.5 and check_number(1, "c", 0.0, 1.0) == 1
    assert check_number(None, "c", 0.0, 1.0, none=True) is None
    for bad in (-0.1, 1.5, True, "0.5", float("nan")):
        with pytest.raises(OptionError, match=r"c must be a number in \[0, 1\], got"):
            check_number(bad, "c", 0.0, 1.0)
    with pytest.raises(OptionError, match=r"c must be a number in \(0, 1\], got 0"):
        check_number(0.0, "c", 0.0, 1.0, open_low=True)
    with pytest.raises(OptionError, match="t must be finite, got inf"):
        check_number(float("inf"), "t", 0.0, float("inf"), "finite")
    assert check_number(float("inf"), "t", 0.0, float("inf"), infinite=True) == float("inf")
