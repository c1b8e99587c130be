"""LearnedStereo: outputs and their shapes, the shipped weights, weights files and their errors, the accuracy of
the shipped weights on a rendered plane, onnxruntime parity."""

import numpy as np
import pytest
import torch

from prismstereo import thesis_setup1
from prismstereo.conventions import to_grey
from prismstereo.depth.result import DepthResult
from prismstereo.epipolar.sweep import fit_sweep, sweep_positions
from prismstereo.errors import OptionError, PrismStereoError, ShapeError
from prismstereo.learned import LEARNED_WEIGHTS, Architecture, LearnedStereo, WeightsError, load_weights
from prismstereo.synthetic import ImageFormation, fronto_parallel_plane, render

pytestmark = pytest.mark.usefixtures("one_thread")

Z_RANGE = (450.0, 1000.0)


@pytest.fixture(scope="module")
def rig():
    return thesis_setup1().downscaled(8)  # 128 x 96, reference half 64 columns


@pytest.fixture(scope="module")
def model(rig):
    return LearnedStereo(rig, Z_RANGE, num_hypotheses=16).eval()


def test_outputs(model, rig):
    image = torch.rand(2, 3, rig.image_height, rig.image_width, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        out = model(image)
    assert isinstance(out, DepthResult)
    size = (2, 1, rig.image_height, rig.reference_width)
    assert out.depth.shape == out.valid.shape == out.confidence.shape == out.index.shape == size
    assert out.match.shape == (2, 2, rig.image_height, rig.reference_width)
    assert out.valid.dtype == torch.bool and out.depth.dtype == torch.float32
    assert torch.isfinite(out.depth).all() and (out.depth >= Z_RANGE[0] - 1e-3).all()
    assert (out.depth <= Z_RANGE[1] + 1e-3).all()
    assert ((out.confidence >= 0) & (out.confidence <= 1)).all()
    assert torch.equal(out.valid, out.confidence >= 0.5)
    fit = fit_sweep(rig, Z_RANGE)  # match = the exact sweep at the estimated hypothesis
    v, u = torch.meshgrid(torch.arange(96.0), torch.arange(64.0), indexing="ij")
    s = out.index[:, 0].double() * (2.0 / 15) - 1.0
    expected = sweep_positions(fit, torch.stack([u, v], -1).double(), s).permute(0, 3, 1, 2)
    torch.testing.assert_close(out.match.double(), expected, atol=2e-2, rtol=0)
    with torch.no_grad():  # colour: its grey (the one grey rule), bit for bit
        grey = model(to_grey(image))
    assert torch.equal(grey.depth, out.depth)


def test_dtype_follows_input(model, rig):
    image = torch.rand(1, 1, rig.image_height, rig.image_width, dtype=torch.float64)
    with torch.no_grad():
        out = model(image)
    assert out.depth.dtype == out.confidence.dtype == out.match.dtype == torch.float64


def test_without_match(rig):
    model = LearnedStereo(rig, Z_RANGE, num_hypotheses=8, with_match=False)
    with torch.no_grad():
        out = model(torch.rand(1, 1, rig.image_height, rig.image_width))
    assert out.match.shape == (1, 2, rig.image_height, rig.reference_width) and out.match.isnan().all()


def test_default_weights_are_small_and_load():
    arch, state, meta = load_weights(LEARNED_WEIGHTS)
    assert arch == Architecture()
    assert LEARNED_WEIGHTS.stat().st_size < 1_000_000
    assert meta["rig"] == "thesis_setup1"


def test_same_weights_on_another_rig(model, rig):
    other = model.for_rig(thesis_setup1().downscaled(4), Z_RANGE, num_hypotheses=8)
    assert other.features is model.features
    with torch.no_grad():
        out = other(torch.rand(1, 1, 192, 256))
    assert out.depth.shape == (1, 1, 192, 128) and torch.isfinite(out.depth).all()


def test_random_initialisation_is_seeded(rig):
    torch.manual_seed(3)
    a = LearnedStereo(rig, Z_RANGE, num_hypotheses=8, weights=None)
    torch.manual_seed(3)
    b = LearnedStereo(rig, Z_RANGE, num_hypotheses=8, weights=None)
    for (name, p), q in zip(a.state_dict().items(), b.state_dict().values(), strict=True):
        assert torch.equal(p, q), name


def test_save_and_load_round_trip(tmp_path, rig):
    torch.manual_seed(0)
    model = LearnedStereo(rig, Z_RANGE, num_hypotheses=8, weights=None)
    path = model.save(tmp_path / "w.pt", note="x")
    again = LearnedStereo(rig, Z_RANGE, num_hypotheses=8, weights=path)
    image = torch.rand(1, 1, rig.image_height, rig.image_width)
    with torch.no_grad():
        torch.testing.assert_close(again(image).depth, model(image).depth)
    assert again.metadata["note"] == "x"


def test_weights_errors(tmp_path, rig):
    with pytest.raises(WeightsError, match="does not exist"):
        LearnedStereo(rig, Z_RANGE, weights=tmp_path / "missing.pt")
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a torch file")
    with pytest.raises(WeightsError, match=r"garbage.pt is not a LearnedStereo weights file \(torch.load cannot"):
        LearnedStereo(rig, Z_RANGE, weights=garbage)
    other = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(3)}, other)
    with pytest.raises(WeightsError, match="not a LearnedStereo weights file"):
        LearnedStereo(rig, Z_RANGE, weights=other)
    small = LearnedStereo(rig, Z_RANGE, num_hypotheses=8, weights=None,
                          architecture=Architecture(feature_channels=16, groups=4))
    path = small.save(tmp_path / "small.pt")
    with pytest.raises(WeightsError, match="was trained for"):
        LearnedStereo(rig, Z_RANGE, weights=path, architecture=Architecture())
    with pytest.raises(WeightsError, match="was trained for"):
        LearnedStereo(rig, Z_RANGE, scale=8)  # the default weights have scale 4
    blob = torch.load(path, weights_only=True)
    blob["architecture"] = {**blob["architecture"], "feature_channels": 32, "groups": 8}  # lies about its shapes
    torch.save(blob, tmp_path / "lying.pt")
    with pytest.raises(WeightsError, match="do not fit"):
        LearnedStereo(rig, Z_RANGE, weights=tmp_path / "lying.pt")
    assert issubclass(WeightsError, PrismStereoError)


def test_option_and_shape_errors(rig, model):
    with pytest.raises(OptionError, match="Choose from: 2, 4, 8"):
        LearnedStereo(rig, Z_RANGE, scale=3, weights=None)
    with pytest.raises(OptionError, match="not divisible by scale"):
        LearnedStereo(thesis_setup1().downscaled(16).replace(image_width=66), Z_RANGE, weights=None)
    with pytest.raises(ShapeError, match="image must be"):
        model(torch.rand(1, 1, 32, 32))
    with pytest.raises(ShapeError, match="image must be"):
        model(torch.rand(1, 2, rig.image_height, rig.image_width))


def test_shipped_weights_on_a_rendered_plane():
    """Median relative error on a textured plane at 600 mm (512 x 384, 24 hypotheses: the training spacing):
    measured 0.11 % with the shipped weights, 3.5 % with random ones (seed 0); the threshold is 1 %."""
    rig = thesis_setup1().downscaled(2)
    capture = render(rig, fronto_parallel_plane(rig, 600.0, seed=1234),
                     ImageFormation(supersample=1, noise_sigma=1 / 255, seed=1))
    covisible = capture.covisible[..., :rig.reference_width]
    errors = {}
    for name, weights in (("shipped", "default"), ("random", None)):
        torch.manual_seed(0)
        model = LearnedStereo(rig, Z_RANGE, num_hypotheses=24, weights=weights, with_match=False).eval()
        with torch.no_grad():
            out = model(capture.image)
        errors[name] = float(((out.depth.double() - 600.0).abs() / 600.0)[covisible].median())
    assert errors["shipped"] < 0.01, errors
    assert errors["random"] > 0.02, errors


def test_onnxruntime_matches_torch(tmp_path, rig, model):
    ort = pytest.importorskip("onnxruntime")
    onnx = pytest.importorskip("onnx")

    class Graph(torch.nn.Module):
        def __init__(self, inner):
            super().__init__()
            self.inner = inner

        def forward(self, image):
            out = self.inner(image)
            return out.depth, out.confidence, out.match

    path = tmp_path / "learned.onnx"
    example = torch.rand(1, 1, rig.image_height, rig.image_width)
    names = ["depth_mm", "confidence", "match"]
    torch.onnx.export(Graph(model).eval(), (example,), str(path), opset_version=18, dynamo=False,
                      input_names=["image"], output_names=names,
                      dynamic_axes={"image": {0: "batch"}, **{n: {0: "batch"} for n in names}})
    onnx.checker.check_model(onnx.load(str(path)))
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    image = torch.rand(2, 1, rig.image_height, rig.image_width, generator=torch.Generator().manual_seed(5))
    depth, confidence, match = session.run(None, {"image": image.numpy()})
    with torch.no_grad():
        ref = model(image)
    np.testing.assert_allclose(depth / ref.depth.numpy(), 1.0, atol=1e-3)
    np.testing.assert_allclose(confidence, ref.confidence.numpy(), atol=1e-3)
    np.testing.assert_allclose(match, ref.match.numpy(), atol=1e-2)


def test_the_learned_model_is_its_own_class_and_describes_its_weights(tmp_path):
    """LearnedStereo is built by its own class (PrismStereo takes no matcher); describe() tells the two models and
    two sets of weights apart (the ONNX cache key); both models copy and pickle as themselves."""
    import copy
    import pickle

    from prismstereo import PrismStereo
    from prismstereo.learned import LearnedStereo

    small = thesis_setup1().downscaled(8)
    model = LearnedStereo(small, (450.0, 1000.0), num_hypotheses=16)
    described = model.describe()
    assert described["model"] == "LearnedStereo" and described["num_hypotheses"] == 16
    assert described["weights_sha256"] == LearnedStereo(small, (450.0, 1000.0)).describe()["weights_sha256"]
    saved = LearnedStereo(small, (450.0, 1000.0), weights=None).save(tmp_path / "w.pt")
    other = LearnedStereo(small, (450.0, 1000.0), weights=saved)
    assert other.describe()["weights_sha256"] != described["weights_sha256"]
    classical = PrismStereo(small, (450.0, 1000.0))
    assert classical.describe()["model"] == "PrismStereo"
    for m in (model, classical):
        assert type(copy.deepcopy(m)) is type(m) and type(pickle.loads(pickle.dumps(m))) is type(m)
    with pytest.raises(TypeError, match="unexpected keyword argument 'matcher'"):
        PrismStereo(small, (450.0, 1000.0), matcher="learned")


def test_hypotheses_follow_the_range_and_the_rig():
    """The default D keeps the shipped weights' spacing (48 over their 450-1000 mm on setup 1), grows with the range
    and the rig's sweep length, and ``for_rig`` follows the new range."""
    from prismstereo import thesis_setup2
    from prismstereo.classical.defaults import default_hypotheses
    from prismstereo.learned import HYPOTHESIS_SPACING_PX, learned_hypotheses

    setup1 = thesis_setup1()
    assert learned_hypotheses(setup1, (450.0, 1000.0)) == 48
    wide = learned_hypotheses(setup1, (200.0, 1600.0))
    assert wide > 3 * 48 and learned_hypotheses(thesis_setup2(), (450.0, 1000.0)) > 48
    # the spacing at the stride: the sweep's length in px (steps of <= 1 px) over D - 1 steps
    length = default_hypotheses(setup1.binned(4), (200.0, 1600.0)) - 1
    assert length / (wide - 1) <= HYPOTHESIS_SPACING_PX < length / (wide - 2)
    small = thesis_setup1().downscaled(4)
    model = LearnedStereo(small, (450.0, 1000.0), with_match=False)
    assert model.num_hypotheses == learned_hypotheses(small, (450.0, 1000.0))
    assert model.for_rig(small, (300.0, 1500.0)).num_hypotheses == learned_hypotheses(small, (300.0, 1500.0))
    with pytest.raises(OptionError, match="spacing_px must be a positive number"):
        learned_hypotheses(small, (450.0, 1000.0), spacing_px=0)
