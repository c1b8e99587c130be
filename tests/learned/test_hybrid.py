"""HybridStereo: a first stage (learned or classical) refined by learned 2-D stages; its data and trainer."""

import math

import numpy as np
import pytest
import torch

from prismstereo import thesis_setup1
from prismstereo.cli import main
from prismstereo.depth.resample import upsample
from prismstereo.depth.result import DepthResult
from prismstereo.epipolar.sweep import sweep_match
from prismstereo.errors import OptionError, ShapeError
from prismstereo.learned import HYBRID_WEIGHTS, HybridArchitecture, HybridStereo, WeightsError
from prismstereo.learned.hybrid import (
    FILL_RADIUS,
    HYBRID_BLOCK_WEIGHTS,
    VALID_CONFIDENCE,
    RefinementInputs,
    load_hybrid_weights,
)
from prismstereo.learned.hybrid_data import (
    hybrid_set,
    photo_scene,
    photographs,
    render_set,
    training_rigs,
    truth_sweep,
)
from prismstereo.learned.hybrid_train import hybrid_loss, train_hybrid, validity_threshold

pytestmark = pytest.mark.usefixtures("one_thread")

Z = (450.0, 1000.0)


@pytest.fixture(scope="module")
def untrained(rig):
    torch.manual_seed(0)
    return HybridStereo(rig, Z, weights=None).eval()


@pytest.fixture(scope="module")
def small():
    torch.manual_seed(0)
    return HybridStereo(thesis_setup1().downscaled(4), Z, weights=None)


@pytest.fixture(scope="module")
def data(small):
    return hybrid_set("test", small.rig, Z, 1, seed=1, model=small)


@torch.no_grad()
def test_outputs_and_shapes(untrained, rig):
    out = untrained(torch.rand(2, 1, rig.image_height, rig.image_width, generator=torch.Generator().manual_seed(0)))
    assert isinstance(out, DepthResult)
    shape = (2, 1, rig.image_height, rig.reference_width)
    assert out.depth.shape == out.valid.shape == out.confidence.shape == out.index.shape == shape
    assert out.match.shape == (2, 2, rig.image_height, rig.reference_width)
    assert out.valid.dtype == torch.bool and out.depth.dtype == torch.float32
    inside = untrained.rays_valid.expand_as(out.valid)
    assert torch.isfinite(out.depth[inside]).all() and (out.confidence[~inside] == 0).all()
    assert Z[0] - 1e-3 <= float(out.depth[inside].min()) and float(out.depth[inside].max()) <= Z[1] + 1e-3


@torch.no_grad()
def test_a_hybrid_whose_last_stage_is_at_one_quarter(rig):
    torch.manual_seed(0)
    model = HybridStereo(rig, Z, weights=None, architecture=HybridArchitecture(quarter=2, iterations=0)).eval()
    image = torch.rand(1, 1, rig.image_height, rig.image_width, generator=torch.Generator().manual_seed(1))
    stages = model.refine(model.initial(image))
    assert model.binning == 1 and len(model.stages) == 0 and len(stages) == 2  # a small sensor: quarter stages at 1/2
    assert "2 at 1/2 (" in model.summary()
    assert stages[-1][0].shape == (1, 1, model.half.image_height, model.half.reference_width)
    assert model(image).depth.shape == (1, 1, rig.image_height, rig.reference_width)


@torch.no_grad()
def test_untrained_stage_keeps_the_classical_estimate(untrained, plane):
    inputs = untrained.initial(plane.image)
    s, logit = untrained.refine(inputs)[-1]
    size = (untrained.half.image_height, untrained.half.reference_width)
    assert torch.allclose(s, upsample(inputs.s, 2, size, mode="bilinear").clamp(-1, 1), atol=1e-6)
    assert torch.equal(logit, torch.zeros_like(logit))
    # on a textured plane the classical block level is close: depth within 0.2 % where it is confident
    out = untrained(plane.image)
    w = untrained.rig.reference_width
    truth = plane.depth[..., :w]
    inner = torch.zeros_like(out.valid)
    inner[..., 8:-8, 8:-8] = True
    seen = inner & plane.covisible[..., :w]
    sel = seen & untrained.classical(plane.image).valid
    rel = ((out.depth - truth).abs() / truth)[sel]
    assert float(sel.sum()) > 0.8 * float(seen.sum()) and float(rel.median()) < 2e-3


@torch.no_grad()
def test_uncovered_blocks_start_from_their_covered_neighbours(rig, plane):
    # the classical level leaves a margin at the sensor's edges; those blocks start near the truth, not at s = 0
    torch.manual_seed(0)
    untrained = HybridStereo(rig, Z, weights=None, architecture=HybridArchitecture(start="classical")).eval()
    inputs = untrained.initial(plane.image)
    w, k = untrained.rig.reference_width, 2 * untrained.binning  # the classical grid's bins
    truth = truth_sweep(torch.nn.functional.avg_pool2d(plane.depth[..., :w].double(), k), untrained.z_range)
    seen = torch.nn.functional.avg_pool2d(plane.covisible[..., :w].double(), k) > 0.99
    covered = inputs.covered > 0
    filled = seen & ~covered
    assert filled.any()
    error = (inputs.s - truth).abs() / untrained.quarter_step
    assert float(error[filled].median()) < 2.0 and float(error[covered & seen].median()) < 0.5
    # beyond FILL_RADIUS blocks of any covered one, nothing to start from: s stays 0
    far = torch.nn.functional.max_pool2d(covered.double(), 2 * FILL_RADIUS + 1, 1, FILL_RADIUS) == 0
    assert torch.equal(inputs.s[far], torch.zeros_like(inputs.s[far]))


def test_architecture_and_option_errors(rig):
    assert HybridArchitecture().inputs == 10
    with pytest.raises(OptionError, match="Choose from: 2, 4"):
        HybridArchitecture(block=3)
    with pytest.raises(OptionError, match="layers must be an int in"):
        HybridArchitecture(layers=1)
    with pytest.raises(OptionError, match="a hybrid needs a refinement stage"):
        HybridArchitecture(iterations=0, quarter=0)
    with pytest.raises(OptionError, match="quarter stages need block 4"):
        HybridArchitecture(block=2, quarter=1, start="classical")
    with pytest.raises(OptionError, match="rig must be a BiPrismRig"):
        HybridStereo("setup1", Z, weights=None)
    with pytest.raises(OptionError, match="not divisible by block 4"):
        HybridStereo(rig.replace(image_width=510, principal_point=(254.5, 191.5)), Z, weights=None,
                     architecture=HybridArchitecture(start="classical"))
    with pytest.raises(OptionError, match="not divisible by the first stage's cells 4"):
        HybridStereo(rig.replace(image_width=510, principal_point=(254.5, 191.5)), Z, weights=None)
    big = thesis_setup1().replace(image_width=1028, principal_point=(513.5, 383.5))  # 4 divides, 8 does not
    with pytest.raises(OptionError, match="not divisible by the first stage's cells 8"):
        HybridStereo(big, Z, weights=None)


def test_shape_errors(untrained, rig):
    with pytest.raises(ShapeError, match="image must be a floating-point"):
        untrained(torch.zeros(1, 1, rig.image_height, rig.image_width, dtype=torch.uint8))
    with pytest.raises(ShapeError, match="image must be a floating-point"):
        untrained(torch.rand(1, 1, 64, 64))


def test_weights_round_trip_and_errors(tmp_path, rig, untrained):
    torch.manual_seed(1)
    arch = HybridArchitecture(channels=8, layers=4)
    model = HybridStereo(rig, Z, weights=None, architecture=arch)
    path = model.save(tmp_path / "w.pt", note="test")
    again = HybridStereo(rig, Z, weights=path)
    assert again.architecture == arch and again.metadata["note"] == "test"
    assert model.valid_confidence == again.valid_confidence == VALID_CONFIDENCE  # no calibrated threshold
    strict = HybridStereo(rig, Z, weights=model.save(tmp_path / "strict.pt", valid_confidence=0.9))
    assert strict.valid_confidence == 0.9 and strict.describe()["valid_confidence"] == 0.9
    image = torch.rand(1, 1, rig.image_height, rig.image_width, generator=torch.Generator().manual_seed(5))
    with torch.no_grad():
        out = strict(image)
    assert torch.equal(out.valid, out.confidence >= 0.9)
    assert all(torch.equal(a, b) for a, b in zip(model.stages.state_dict().values(),
                                                 again.stages.state_dict().values(), strict=True))
    assert again.describe()["weights_sha256"] == model.describe()["weights_sha256"]
    assert again.describe()["weights_sha256"] != untrained.describe()["weights_sha256"]
    with pytest.raises(WeightsError, match="does not exist"):
        load_hybrid_weights(tmp_path / "missing.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a weights file")
    with pytest.raises(WeightsError, match="is not a HybridStereo weights file"):
        load_hybrid_weights(tmp_path / "junk.pt")
    torch.save({"format": "something else"}, tmp_path / "other.pt")
    with pytest.raises(WeightsError, match="format"):
        load_hybrid_weights(tmp_path / "other.pt")


@pytest.mark.parametrize("path, start", [(HYBRID_WEIGHTS, "learned"), (HYBRID_BLOCK_WEIGHTS, "classical")],
                         ids=["default", "block"])
def test_shipped_weights_load_and_keep_a_textured_plane(rig, plane, path, start):
    arch, state, meta = load_hybrid_weights(path)
    assert path.stat().st_size < 200_000 and meta["steps"] >= 1 and "variants" in meta
    assert 0.5 <= meta["valid_confidence"] < 1.0  # calibrated on the training captures
    assert arch.start == start and ("start_architecture" in meta) == (start == "learned")
    model = HybridStereo(rig, Z, weights=path).eval()
    assert model.rescored and (model.start is None) == (start == "classical")
    with torch.inference_mode():
        out, classical = model(plane.image), model.classical(plane.image)
    w = rig.reference_width
    truth, covisible = plane.depth[..., :w], plane.covisible[..., :w]
    inner = torch.zeros_like(out.valid)
    inner[..., 8:-8, 8:-8] = True
    confident = inner & covisible & classical.valid  # the classical estimate is exact there
    rel_h = ((out.depth - truth).abs() / truth)[confident]
    rel_c = ((classical.depth - truth).abs() / truth)[confident]
    assert float(rel_h.mean()) <= float(rel_c.mean()) + 2e-4  # the learned stage does not make it worse
    assert float((out.valid & inner & covisible).sum()) >= 0.95 * float((inner & covisible).sum())


def test_last_stage_option_errors(rig):
    with pytest.raises(OptionError, match="Unknown last_stage 'band'. Choose from: 'exact', 'learned'"):
        HybridStereo(rig, Z, weights=None, last_stage="band")
    assert HybridStereo(rig, Z, weights=None, last_stage="learned").exact is None


def test_onnxruntime_matches_torch(tmp_path, untrained, rig, plane):
    from prismstereo.export import OnnxDepth, export_onnx

    torch.manual_seed(3)
    model = HybridStereo(rig, Z, weights=None, architecture=HybridArchitecture(quarter=1)).eval()
    with torch.no_grad():
        for p in model.stages.parameters():
            p.normal_(0.0, 0.05)
    noise = torch.rand(1, 1, rig.image_height, rig.image_width, generator=torch.Generator().manual_seed(4))
    image = torch.cat([noise, plane.image[:, :1]])  # the plane: the exact last stage replaces most of it
    image[1, :, 100:104, 50:54] = float("nan")  # bad pixels: the graph drops the same pixels
    image[1, :, 200, rig.reference_width + 80] = float("inf")
    with torch.no_grad():
        ref = model(image)
    graph = OnnxDepth(export_onnx(model, tmp_path / "hybrid.onnx"))
    out = graph(image.numpy())
    depth = torch.as_tensor(np.asarray(out.depth))
    # the exact stage's choice may flip at pixels on its thresholds: there the two differ by <= 1/2 step of s
    assert float(torch.isclose(depth, ref.depth, rtol=1e-4).float().mean()) > 0.999
    steps = (truth_sweep(depth, model.z_range) - truth_sweep(ref.depth, model.z_range)).abs() / model.exact.level.step
    assert float(steps.max()) <= 0.5 + 1e-3
    assert torch.allclose(torch.as_tensor(np.asarray(out.confidence)), ref.confidence, atol=1e-4)
    agree = torch.as_tensor(np.asarray(out.valid)) == ref.valid
    assert float(agree.float().mean()) > 0.999  # pixels at confidence 0.5 may round either way
    dropped = torch.as_tensor(np.asarray(out.confidence)) == 0
    assert torch.equal(dropped, ref.confidence == 0) and dropped[1, :, 100:104, 50:54].all()


def test_training_data(data, small):
    rig, b = small.rig, small.binning  # a small sensor: the stages at full resolution
    h, w = rig.image_height // b, rig.reference_width // b
    assert b == 1 and data.image.shape == (1, 2, h, rig.image_width // b)
    for t in (data.s, data.confidence, data.covered):  # the classical grid, 2 b x 2 b-binned
        assert t.shape == (1, 1, h // 2, w // 2)
    for t in (data.truth, data.known, data.rays):
        assert t.shape == (1, 1, h, w)
    assert data.known.dtype == torch.bool and float(data.known.float().mean()) > 0.3
    assert torch.isfinite(data.truth[data.known]).all()
    assert [name for name, _, _ in training_rigs()][0] == "setup1" and len(training_rigs()) >= 5
    scene = photo_scene(photographs(("camera",))[0], torch.Generator().manual_seed(0), (450.0, 900.0))
    field = scene.surfaces[0]
    assert 450.0 <= field.z_min and field.z_max <= 900.0
    with pytest.raises(OptionError, match="Unknown photograph"):
        photographs(("lena",))
    with pytest.raises(OptionError, match="count must be an int >= 1"):
        hybrid_set("test", rig, Z, 0)
    with pytest.raises(OptionError, match="binning must be 1 or 2, got 4"):
        render_set("test", rig, Z, 1, binning=4)


def test_loss_and_training_resume_from_a_checkpoint(tmp_path, data, small, monkeypatch):
    inputs = RefinementInputs(data.image[:1], data.s[:1], data.confidence[:1], data.covered[:1])
    loss = hybrid_loss(small, inputs, data.truth[:1], data.known[:1], data.rays[:1])
    assert loss.shape == () and math.isfinite(loss.item())
    options = dict(steps=6, sets=[data], progress=False, crop=(32, 32), batch_size=1, checkpoint_every=2,
                   architecture=HybridArchitecture(quarter=1, channels=8))
    whole = train_hybrid(tmp_path / "whole.pt", **options)
    calls = {"n": 0}
    real = hybrid_loss

    def interrupted(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 5:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    import prismstereo.learned.hybrid_train as module

    monkeypatch.setattr(module, "hybrid_loss", interrupted)
    with pytest.raises(KeyboardInterrupt):
        train_hybrid(tmp_path / "resumed.pt", **options)
    assert (tmp_path / "resumed.ckpt").is_file() and not (tmp_path / "resumed.pt").exists()
    monkeypatch.setattr(module, "hybrid_loss", real)
    resumed = train_hybrid(tmp_path / "resumed.pt", **options)
    assert not (tmp_path / "resumed.ckpt").exists()
    assert torch.equal(whole.losses, resumed.losses)
    (_, a, meta_a), (_, b, meta_b) = load_hybrid_weights(whole.path), load_hybrid_weights(resumed.path)
    assert all(torch.equal(a[k], b[k]) for k in a)
    # the validity threshold, calibrated on the training captures after training
    trained = HybridStereo(small.rig, Z, weights=whole.path)
    assert meta_a["valid_confidence"] == meta_b["valid_confidence"] == validity_threshold([trained], [data], 0.03)
    assert 0.0 <= validity_threshold([trained], [data], 0.5) <= meta_a["valid_confidence"] <= 1.0
    with pytest.raises(OptionError, match="steps must be an int >= 1"):
        train_hybrid(tmp_path / "x.pt", **{**options, "steps": 0})


def test_cli_train_options_of_each_model(tmp_path, capsys):
    assert main(["train", "--out", str(tmp_path / "w.pt")]) == 2
    assert "--rig is required" in capsys.readouterr().err
    assert main(["train", "--model", "hybrid", "--rig", "thesis_setup1", "--z-range", "400", "900",
                 "--out", str(tmp_path / "w.pt")]) == 2
    assert "--rig, --z-range apply to --model learned only" in capsys.readouterr().err


@pytest.mark.parametrize("z_range", [Z, (200.0, 1600.0)])
def test_steps_follow_the_range(rig, untrained, z_range):
    """A step of s moves each pixel's match by <= 1 px at its stage's resolution whatever the range (the offsets
    reach the same pixels), so a wider range has more, smaller steps."""
    narrow = untrained  # over Z = 450-1000 mm
    model = narrow if z_range == Z else HybridStereo(rig, z_range, weights=None)
    valid = model.rays_valid[0, 0]
    b = model.binning
    for coefficients, step, factor in ((model.coefficients, model.step, b), (model.quarter_coefficients,
                                                                           model.quarter_step, 2 * b)):
        h, w = coefficients.shape[-2:]
        inside = valid[factor // 2::factor, factor // 2::factor][:h, :w]
        moves = []
        for s in torch.linspace(-1.0, 1.0, 9):
            slope = sweep_match(coefficients, torch.full((1, 1, h, w), float(s)))[1]
            moves.append((slope * step).norm(dim=1)[0][inside].max())
        assert 0.5 < float(torch.stack(moves).max()) <= 1.05
    assert (model.step < narrow.step) == (z_range != Z)


def test_the_learned_start_keeps_more_of_a_photograph_than_the_block_start(photo="gravel", seed=105):
    """A photograph as a surface with depth jumps (training's kind of scene, not its captures), 512 x 384: the default
    (the learned first stage) keeps a larger share of the co-visible pixels at <= 3 % wrong than the same chain started
    from the classical block level (the block-start weights)."""
    from prismstereo.learned.hybrid_data import photo_scene
    from prismstereo.matching.confidence import confidence_threshold
    from prismstereo.synthetic import ImageFormation, render

    rig = thesis_setup1().downscaled(2)
    capture = render(rig, photo_scene(photographs((photo,))[0], torch.Generator().manual_seed(seed), Z),
                     ImageFormation(supersample=1, noise_sigma=1 / 255))
    w = rig.reference_width
    seen = capture.covisible[..., :w] & torch.isfinite(capture.depth[..., :w])
    kept = {}
    for name, weights in (("learned", HYBRID_WEIGHTS), ("block", HYBRID_BLOCK_WEIGHTS)):
        with torch.inference_mode():
            out = HybridStereo(rig, Z, weights=weights).eval()(capture.image)
        right = ((out.depth - capture.depth[..., :w]).abs() <= 0.01 * capture.depth[..., :w])[seen]
        kept[name] = confidence_threshold(out.confidence[seen], right, 0.03).kept / int(seen.sum())
    assert kept["learned"] > kept["block"] + 0.04, kept
