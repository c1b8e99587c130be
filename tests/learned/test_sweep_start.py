"""SweepStart: learned features correlated along the exact sweep at 1/8, aggregated by 2-D convolutions; its trainer."""

import copy
import dataclasses

import numpy as np
import pytest
import torch

from prismstereo import thesis_setup1, thesis_setup2
from prismstereo.classical.defaults import default_hypotheses
from prismstereo.errors import OptionError, ShapeError
from prismstereo.learned.hybrid_data import render_set
from prismstereo.learned.network import normalise_image
from prismstereo.learned.start_train import binned_rendered, start_loss, start_set, train_start
from prismstereo.learned.sweep_start import (
    SCALE,
    START_WEIGHTS,
    StartArchitecture,
    SweepStart,
    load_start,
    windowed_expectation,
)
from prismstereo.learned.weights import WeightsError
from prismstereo.synthetic import ImageFormation, fronto_parallel_plane, render

pytestmark = pytest.mark.usefixtures("one_thread")

Z = (450.0, 1000.0)


@pytest.fixture(scope="module")
def rig():
    return thesis_setup1().downscaled(4)  # 256 x 192


@pytest.fixture(scope="module", params=[("rectified", 0, "fine"), ("sweep", 0, "fine"), ("rectified", 2, "pooled")],
                ids=["rectified", "sweep", "rectified-pooled-levels"])
def start(rig, request):
    torch.manual_seed(0)
    sampling, levels, aggregation = request.param
    return SweepStart(rig, Z, architecture=StartArchitecture(sampling=sampling, levels=levels,
                                                             aggregation=aggregation)).eval()


def _binned(rig, image):
    return normalise_image(torch.nn.functional.avg_pool2d(image, 2))


def test_shapes_and_coverage(rig, start):
    out = start(torch.randn(2, 2, 96, 128))
    h, w = rig.image_height // SCALE, rig.binned(SCALE).reference_width
    assert out.s.shape == out.confidence.shape == out.covered.shape == (2, 1, h, w)
    assert out.scores.shape == (2, start.num_hypotheses, *start.valid.shape[1:])
    assert out.s.abs().max() <= 1.0 and (out.confidence <= 1.0 + 1e-6).all()
    # no depth where no hypothesis samples the other half: confidence 0 there
    uncovered = out.covered == 0
    assert uncovered.any() and (out.confidence[uncovered] == 0).all()


@pytest.mark.parametrize("sampling", ["rectified", "sweep"])
def test_hypotheses_follow_the_range_and_rig(rig, sampling):
    arch = StartArchitecture(sampling=sampling)
    for z_range in ((450.0, 1000.0), (250.0, 1300.0)):
        for r in (rig, thesis_setup2().downscaled(4)):
            model = SweepStart(r, z_range, architecture=arch)
            d = default_hypotheses(r.binned(SCALE), z_range)  # <= 1 px apart at 1/8 on every pixel
            if sampling == "sweep":
                assert model.num_hypotheses == d
                assert torch.equal(model.values, torch.linspace(-1, 1, d))
                assert np.allclose(model.volume.depths[[0, -1]].tolist(), z_range)
            else:  # whole-pixel shifts spanning every pixel's sweep over the range
                assert torch.equal(model.values, torch.arange(model.values[0], model.values[-1] + 1))
                assert abs(model.num_hypotheses - d) <= 4
    assert (SweepStart(rig, (250.0, 1300.0), architecture=arch).num_hypotheses
            > SweepStart(rig, Z, architecture=arch).num_hypotheses)


def test_bad_options(rig, start):
    with pytest.raises(OptionError, match="groups"):
        StartArchitecture(features=10, groups=4)
    with pytest.raises(OptionError, match=r"window must be an int in \[1, 8\]"):
        StartArchitecture(window=0)
    with pytest.raises(OptionError, match=r"levels must be an int in \[0, 4\]"):
        StartArchitecture(levels=5)
    with pytest.raises(OptionError, match="Unknown aggregation 'coarse'. Choose from: fine, pooled"):
        StartArchitecture(aggregation="coarse")
    with pytest.raises(OptionError, match="Unknown sampling 'grid'. Choose from: sweep, rectified"):
        StartArchitecture(sampling="grid")
    with pytest.raises(OptionError, match="not divisible by 8"):
        SweepStart(rig.replace(image_width=252), Z)
    with pytest.raises(OptionError, match="BiPrismRig"):
        SweepStart("setup1", Z)
    with pytest.raises(ShapeError, match=r"\(B, 2, 96, 128\)"):
        start(torch.randn(1, 2, 96, 64))


def test_windowed_expectation_keeps_the_stronger_mode_and_has_gradients():
    scores = torch.tensor([0.0, 5.0, 0.0, 0.0, 4.9]).view(1, 5, 1, 1)
    value, mass = windowed_expectation(scores, torch.arange(5.0), 1)
    p = torch.softmax(scores.flatten(), 0)
    assert float(mass) == pytest.approx(float(p[:3].sum()))
    assert float(value) == pytest.approx(float(p[1] + 2 * p[2]) / float(p[:3].sum()))
    x = torch.randn(2, 7, 3, 4, dtype=torch.float64, requires_grad=True)
    values = torch.linspace(-1, 1, 7, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda t: windowed_expectation(t, values, 2), (x,))


def test_weights_round_trip_and_run_on_other_sensors(rig, start, tmp_path):
    from prismstereo.learned.sweep_start import START_FORMAT
    from prismstereo.learned.weights import write_weights

    path = write_weights(tmp_path / "w.pt", START_FORMAT, start.architecture, start.weights(), {})
    image = torch.randn(1, 2, 96, 128)
    again = load_start(rig, Z, path).eval()
    with torch.no_grad():
        assert torch.equal(again(image).s, start(image).s)
        for r in (thesis_setup1().downscaled(2), thesis_setup2().downscaled(4)):  # other sensors and rigs
            other = load_start(r, (300.0, 900.0), path)
            out = other(torch.randn(1, 2, r.image_height // 2, r.image_width // 2))
            assert out.s.shape[-2:] == (r.image_height // 8, r.binned(8).reference_width)
    with pytest.raises(WeightsError, match="do not fit"):
        SweepStart(rig, Z, architecture=StartArchitecture(channels=2)).load_weights(start.weights())
    levels = 1 if start.architecture.levels != 1 else 2  # coarse layers the weights lack, or hold and may not
    with pytest.raises(WeightsError, match="do not fit"):
        SweepStart(rig, Z, architecture=dataclasses.replace(start.architecture, levels=levels)).load_weights(
            start.weights())


def test_coarse_levels_see_farther():
    """A score on the finest grid depends on the capture farther away with the coarse levels, and farther still when
    the aggregation works on the pooled grid (rows of the 512 x 384 sensor's centre cell; its columns see it all)."""
    rig = thesis_setup1().downscaled(2)
    reach = {}
    for levels, aggregation in ((0, "fine"), (2, "fine"), (2, "pooled")):
        torch.manual_seed(0)
        model = SweepStart(rig, Z, architecture=StartArchitecture(levels=levels, aggregation=aggregation))
        image = torch.randn(1, 2, 192, 256, requires_grad=True)
        with torch.no_grad():
            for p in model.parameters():  # positive weights: no dead units, every path carries a gradient
                p.copy_(p.abs() + 0.01)
        scores = model.scores(image)
        scores[0, :, scores.shape[2] // 2, scores.shape[3] // 2].sum().backward()
        rows = (image.grad.abs().sum((0, 1)) > 0).any(1).nonzero().flatten()
        reach[levels, aggregation] = int(rows.max() - rows.min())
    assert reach[2, "fine"] > 1.5 * reach[0, "fine"]
    assert reach[2, "pooled"] > reach[2, "fine"]


def test_onnxruntime_matches_torch(start, tmp_path):
    ort = pytest.importorskip("onnxruntime")
    start = copy.deepcopy(start)
    gen = torch.Generator().manual_seed(4)
    with torch.no_grad():  # live units everywhere: an untrained net's scores tie where its ReLUs are dead
        for p in start.parameters():
            p.copy_(0.3 * torch.randn(p.shape, generator=gen) + (0.05 if p.dim() == 1 else 0.0))
    image = torch.randn(1, 2, 96, 128, generator=torch.Generator().manual_seed(1))
    path = tmp_path / "start.onnx"

    class Graph(torch.nn.Module):
        def __init__(self, start):
            super().__init__()
            self.start = start

        def forward(self, x):
            out = self.start(x)
            return out.s, out.confidence

    torch.onnx.export(Graph(start), (image,), str(path), input_names=["image"], opset_version=17, dynamo=False)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    s, confidence = session.run(None, {"image": image.numpy()})
    with torch.no_grad():
        out = start(image)
    # untrained, some scores tie exactly (dead ReLUs): where the best two are apart, the same pick
    top = out.scores.topk(2, 1).values
    clear = (top[:, 0] - top[:, 1] > 1e-3).unsqueeze(1).float()
    if start.architecture.sampling == "rectified":
        clear = start.volume.back(clear.transpose(-1, -2), "nearest") > 0.5  # rectified grid -> reference grid
    clear = clear.bool() & (out.covered > 0)
    assert clear.double().mean() > 0.5  # the pooled scores carried back to 1/8 tie more often
    np.testing.assert_allclose(s[clear.numpy()], out.s[clear].numpy(), atol=1e-3)  # a hundredth of a step
    # the coarse levels' convolutions add float32 rounding to the scores: 1e-4 of the probability mass on a pixel
    np.testing.assert_allclose(confidence[clear.numpy()], out.confidence[clear].numpy(), atol=5e-4)


@pytest.fixture(scope="module")
def small_set(rig):
    rendered = render_set("test", rig, Z, 2, seed=3)
    return start_set("test", rendered, rig, Z)


def test_binned_captures_are_a_sensor_of_half_the_size(rig, small_set):
    rendered = render_set("test", rig, Z, 2, seed=3)  # the fixture's renders, from scikit-image and the seed
    half = binned_rendered(rendered)
    assert half.grey.shape[-2:] == (rendered.grey.shape[-2] // 2, rendered.grey.shape[-1] // 2)
    # a block's truth is the mean of four known ones, unknown if any of them is
    blocks = rendered.known[..., :half.known.shape[-2] * 2, :half.known.shape[-1] * 2].unfold(2, 2, 2).unfold(3, 2, 2)
    assert torch.equal(half.known, blocks.flatten(-2).all(-1))
    n, _, i, j = (int(x) for x in half.known.nonzero()[half.known.sum() // 2])  # a block in the middle of the known
    assert float(half.truth[n, 0, i, j]) == pytest.approx(float(rendered.truth[n, 0, 2 * i:2 * i + 2,
                                                                                  2 * j:2 * j + 2].mean()))
    assert half.known.any() and torch.isnan(half.truth[~half.known]).all()
    data = start_set("half", half, rig.binned(2), Z)
    assert data.truth.shape[-2:] == (rig.image_height // 16, rig.binned(16).reference_width)


def test_training_lowers_the_loss_and_resumes(rig, small_set, tmp_path, monkeypatch):
    assert small_set.known.any() and small_set.truth[small_set.known].abs().max() <= 1.0
    with pytest.raises(OptionError, match="steps must be an int >= 1"):
        train_start(tmp_path / "x.pt", steps=0, sets=[small_set])
    image = normalise_image(small_set.grey)
    torch.manual_seed(0)
    with torch.no_grad():
        before = float(start_loss(SweepStart(rig, Z), image, small_set.truth, small_set.known))
    options = dict(steps=6, batch_size=1, sets=[small_set], progress=False, checkpoint_every=2, learning_rate=5e-3)
    whole = train_start(tmp_path / "whole.pt", **options)
    trained = load_start(rig, Z, whole.path)
    assert float(start_loss(trained, image, small_set.truth, small_set.known)) < before
    import prismstereo.learned.start_train as module

    calls, real = {"n": 0}, start_loss

    def interrupted(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 5:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(module, "start_loss", interrupted)
    with pytest.raises(KeyboardInterrupt):
        train_start(tmp_path / "resumed.pt", **options)
    assert (tmp_path / "resumed.ckpt").is_file() and not (tmp_path / "resumed.pt").exists()
    monkeypatch.setattr(module, "start_loss", real)
    resumed = train_start(tmp_path / "resumed.pt", **options)
    assert not (tmp_path / "resumed.ckpt").exists() and torch.equal(whole.losses, resumed.losses)
    a, b = load_start(rig, Z, whole.path).weights(), load_start(rig, Z, resumed.path).weights()
    assert all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize("setup", [thesis_setup1, thesis_setup2])
def test_shipped_weights_start_a_textured_plane_within_a_step(setup):
    """The shipped first stage on held-out textured planes, at a range and sensor size it was not trained on: every
    pixel whose true hypotheses sample the other half within one hypothesis of the truth."""
    rig, z_range = setup().downscaled(4), (300.0, 1100.0)
    capture = render(rig, fronto_parallel_plane(rig, 640.0, seed=21), ImageFormation(supersample=2,
                                                                                    noise_sigma=1 / 255))
    model = load_start(rig, z_range, START_WEIGHTS).eval()
    with torch.no_grad():
        out = model(_binned(rig, capture.image[:, :1].float()))
    truth = (1 / 640.0 - 1 / z_range[0]) / (1 / z_range[1] - 1 / z_range[0]) * 2 - 1
    w = out.s.shape[-1] * SCALE  # blocks whose 64 pixels the other half sees
    seen = -torch.nn.functional.max_pool2d(-capture.covisible[..., :w].float(), SCALE) > 0.5
    assert seen.double().mean() > 0.6
    assert ((out.s - truth).abs() <= model.step)[seen].double().mean() > 0.98


def test_hybrid_refines_the_learned_start(rig, tmp_path):
    from prismstereo.depth.resample import upsample
    from prismstereo.learned import HybridArchitecture, HybridStereo
    from prismstereo.learned.hybrid_data import truth_sweep

    with pytest.raises(OptionError, match="Unknown start 'x'. Choose from: classical, learned"):
        HybridArchitecture(start="x")
    with pytest.raises(OptionError, match="needs block 4"):
        HybridArchitecture(start="learned", block=2, quarter=0)
    torch.manual_seed(0)
    model = HybridStereo(rig, Z, weights=None, architecture=HybridArchitecture(start="learned")).eval()
    assert model.summary().startswith("hybrid: learned first stage (")
    image = torch.rand(1, 1, rig.image_height, rig.image_width, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        inputs = model.initial(image)
        # a small sensor: the stages at full resolution, the first stage on the capture as the 2 x 2-binned capture
        # of a sensor twice as fine, so on 4 x 4 cells; carried to the classical grid's 2 x 2 bins
        assert model.binning == 1 and model.start.rig == rig.unbinned(2)
        out = model.start(normalise_image(image))
        carried = upsample(out.s, 2, tuple(inputs.s.shape[-2:]), mode="bilinear")
    assert torch.allclose(inputs.s, carried)
    k = 2 * model.binning
    assert inputs.s.shape[-2:] == (rig.image_height // k, rig.binned(k).reference_width)
    # the exported graph runs the first stage too (a textured capture: the shipped start's picks are clear)
    from prismstereo.export import OnnxDepth, export_onnx

    capture = render(rig, fronto_parallel_plane(rig, 600.0, seed=5), ImageFormation(noise_sigma=1 / 255))
    with torch.no_grad():
        ref = model(capture.image[:, :1].float())
    out = OnnxDepth(export_onnx(model, tmp_path / "hybrid.onnx"))(capture.image[:, :1].float().numpy())
    depth = torch.as_tensor(np.asarray(out.depth))  # the exact stage may flip at its thresholds (<= 1/2 step)
    assert float(torch.isclose(depth, ref.depth, rtol=1e-4).float().mean()) > 0.999
    steps = (truth_sweep(depth, model.z_range) - truth_sweep(ref.depth, model.z_range)).abs() / model.exact.level.step
    assert float(steps.max()) <= 0.5 + 1e-3
    # the weights file holds the first stage too, and a model built from it starts where this one does
    path = model.save(tmp_path / "hybrid.pt")
    with torch.no_grad():
        model.start.head.bias.add_(1.0)
        again = HybridStereo(rig, Z, weights=path)
        assert again.architecture.start == "learned"
        assert not torch.equal(again.start.head.bias, model.start.head.bias)
        assert torch.allclose(again.initial(image).s, inputs.s)


def test_hybrid_weights_carry_their_first_stage_architecture(rig, tmp_path):
    """A hybrid trained on a first stage of another architecture than the shipped one loads that one."""
    from prismstereo.learned import HybridArchitecture, HybridStereo
    from prismstereo.learned.hybrid import HYBRID_FORMAT
    from prismstereo.learned.weights import read_weights, write_weights

    torch.manual_seed(0)
    model = HybridStereo(rig, Z, weights=None, architecture=HybridArchitecture(start="learned")).eval()
    other = StartArchitecture(levels=1, channels=8)
    assert other != model.start.architecture
    model.start = SweepStart(model.start.rig, Z, architecture=other).eval()
    path = model.save(tmp_path / "hybrid.pt")
    arch, state, metadata = read_weights(path, HYBRID_FORMAT, HybridArchitecture, "HybridStereo")
    assert metadata["start_architecture"] == dataclasses.asdict(other)
    again = HybridStereo(rig, Z, weights=path).eval()
    assert again.start.architecture == other
    image = torch.rand(1, 1, rig.image_height, rig.image_width, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        assert torch.equal(again.initial(image).s, model.initial(image).s)
    metadata["start_architecture"] = {"levels": 9}
    write_weights(tmp_path / "bad.pt", HYBRID_FORMAT, arch, state, metadata)
    with pytest.raises(WeightsError, match="invalid first stage architecture"):
        HybridStereo(rig, Z, weights=tmp_path / "bad.pt")
