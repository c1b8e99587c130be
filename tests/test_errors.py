import pytest
import torch

from prismstereo.errors import (
    OptionError,
    PrismStereoError,
    RigError,
    ShapeError,
    check_floating,
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
    from prismstereo.model import DepthResult, PrismStereo
    from prismstereo.stream import DepthStream

    assert prismstereo.PrismStereo is PrismStereo and prismstereo.DepthResult is DepthResult
    assert prismstereo.DepthStream is DepthStream
    assert {"PrismStereo", "DepthResult", "DepthStream"} <= set(prismstereo.__all__)
    with pytest.raises(AttributeError, match="has no attribute 'Nope'"):
        prismstereo.Nope  # noqa: B018
