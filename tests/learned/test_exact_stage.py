"""The hybrid's exact last stage: the classical band's fit around the learned estimate."""

import pytest
import torch

from prismstereo import PrismStereo, thesis_setup1
from prismstereo.epipolar.sweep import fit_sweep, sweep_coefficients, sweep_match
from prismstereo.errors import ShapeError
from prismstereo.learned import HybridStereo
from prismstereo.learned.exact_stage import EXACT_AGREEMENT, EXACT_BAND, ExactStage, exact_config
from prismstereo.learned.hybrid_data import truth_sweep
from prismstereo.synthetic import ImageFormation, fronto_parallel_plane, render

pytestmark = pytest.mark.usefixtures("one_thread")

Z = (450.0, 1000.0)


def test_exact_last_stage_keeps_a_textured_plane_as_exact_as_the_classical_model(rig, plane):
    exact, learned = (HybridStereo(rig, Z, last_stage=last).eval() for last in ("exact", "learned"))
    assert exact.describe()["last_stage"] == "exact" and f"exact band +-{EXACT_BAND}" in exact.summary()
    assert learned.exact is None and "exact band" not in learned.summary()
    with torch.inference_mode():
        out, plain, classical = exact(plane.image), learned(plane.image), PrismStereo(rig, Z)(plane.image)
    w = rig.reference_width
    truth, covisible = plane.depth[..., :w], plane.covisible[..., :w]
    inner = torch.zeros_like(out.valid)
    inner[..., 8:-8, 8:-8] = True
    sel = inner & covisible & out.valid & classical.valid
    assert float(sel.sum()) >= 0.9 * float((inner & covisible).sum())
    error = {name: float(((r.depth - truth).abs() / truth)[sel].mean())
             for name, r in (("exact", out), ("learned", plain), ("classical", classical))}
    assert error["exact"] <= 1.2 * error["classical"], error  # the target
    assert error["exact"] < error["learned"], error
    # without a confidence head the confidence is the learned stages'; the fit moves s by at most EXACT_AGREEMENT
    # steps
    head, exact.head = exact.head, None
    with torch.inference_mode():
        assert torch.equal(exact(plane.image).confidence, plain.confidence)
    exact.head = head
    moved = (out.index - plain.index).abs() * learned.classical.step / exact.exact.level.step
    assert float(moved[inner].max()) <= EXACT_AGREEMENT + 1e-3
    assert float((moved[sel] > 1e-6).float().mean()) > 0.5  # the fit replaced most of the plane


@pytest.mark.parametrize(("downscale", "binning"), [(1, 2), (2, 1)])
def test_the_stage_keeps_the_estimate_where_it_cannot_fit(downscale, binning):
    # a large sensor fits on its 2 x 2-binned grid, a small one on its full-resolution grid (the classical rule)
    rig = thesis_setup1().downscaled(downscale)
    stage = ExactStage(rig, Z)
    grid = stage.rig
    assert stage.binning == binning and grid.image_width == rig.image_width // binning
    flat = torch.full((1, 1, grid.image_height, grid.image_width), 0.5)
    s = torch.linspace(-0.5, 0.5, grid.reference_width).expand(1, 1, grid.image_height, -1).contiguous()
    with torch.inference_mode():  # no texture: no valid fit, every pixel keeps its estimate
        out = stage(flat, s)
    assert torch.equal(out, s)


def test_config_and_shape_errors(rig):
    config = exact_config(rig, Z)
    assert config.search.band == EXACT_BAND and config.search.band_edges == "clamp"
    assert config.validity.validity == "thresholds" and config.validity.occlusion_tolerance is None
    assert config.refinement.smoothing > 0 and config.refinement.refinement == "parabola"
    stage = ExactStage(rig, Z)
    grey = torch.rand(1, 1, rig.image_height, rig.image_width)
    with pytest.raises(ShapeError, match=r"s must have shape \(B, 1, 384, 256\)"):  # the estimate on the grid
        stage(grey, torch.zeros(1, 1, 10, 10))
    with pytest.raises(ShapeError, match="but the rig's sensor is"):
        stage(grey[..., :64, :64], torch.zeros(1, 1, rig.image_height, rig.reference_width))
    with pytest.raises(ShapeError, match="grey has 1 images, s 2"):
        stage(grey, torch.zeros(2, 1, rig.image_height, rig.reference_width))
    with pytest.raises(ShapeError, match=r"s must have shape \(B, 1, 384, 256\)"):
        stage.evidence(grey, torch.zeros(1, 1, 10, 10))


def test_evidence_is_what_the_fit_found(rig, plane):
    stage = ExactStage(rig, Z)
    w = stage.rig.reference_width
    truth = truth_sweep(plane.depth[..., :w].double(), Z).nan_to_num(0.0).to(plane.image.dtype)
    s = truth + 0.3 * stage.level.step * torch.sin(torch.arange(w, dtype=truth.dtype) / 7.0)  # off by < 0.3 steps
    s[..., :, : w // 4] += 8 * stage.level.step  # a quarter 8 steps off: no fit taken there
    with torch.inference_mode():
        out = stage.evidence(plane.image, s)
        assert torch.equal(out.s, stage(plane.image, s))
    assert out.reference.shape == s.shape and torch.equal(out.reference, plane.image[..., :w])
    taken = out.taken.bool()
    assert torch.equal(out.s, torch.where(taken, out.s, s)) and bool((out.move[taken] <= EXACT_AGREEMENT).all())
    assert float(out.similarity.min()) >= 0.0 and float(out.similarity.max()) <= 1.0
    inner = torch.zeros_like(taken)
    inner[..., 8:-8, 8:-8] = True
    column = torch.arange(w)
    near, far = inner & (column >= w // 4 + 8), inner & (column < w // 4 - 8)  # apart from the 15 x 15 smoothing
    assert float(taken[near].float().mean()) > 0.9 and float(taken[far].float().mean()) < 0.02
    assert float(out.similarity[near].median()) > 0.9
    # the fit lands on the truth: the move is the offset given
    offset = ((s - truth) / stage.level.step).abs()
    assert float((out.move - offset)[near & taken].abs().median()) < 0.1


@pytest.mark.parametrize(("sensor", "binning"), [("800x400 setup 1", 2), ("480x360 other rig", 1)])
def test_the_same_weights_run_on_other_sensors(sensor, binning):
    """The shipped weights and the exact stage on sensors and a rig no training saw (512 x 384: the plane test above),
    the stages on the 2 x 2-binned grid of a large sensor and on a small sensor's own: a textured plane within 0.1 %,
    the match where the depth puts it."""
    other = thesis_setup1().replace(image_width=800, image_height=400, principal_point=(399.5, 199.5)) if (
        sensor.startswith("800")) else thesis_setup1().replace(
        alpha_deg=9.0, refractive_index=1.517, focal_length_mm=12.0, prism_thickness_mm=8.0,
        apex_distance_mm=150.0, pixel_size_mm=0.0074, image_width=480, image_height=360,
        principal_point=(239.5, 179.5))
    capture = render(other, fronto_parallel_plane(other, 600.0, seed=4),
                     ImageFormation(supersample=1, noise_sigma=1 / 255))  # pixel centres: 1/9 of the default's rays
    model = HybridStereo(other, Z).eval()
    assert model.binning == binning
    with torch.inference_mode():
        out = model(capture.image)
        v, u = torch.meshgrid(*(torch.arange(n, dtype=torch.float64) for n in out.depth.shape[-2:]), indexing="ij")
        s = truth_sweep(out.depth.double(), model.z_range)
        full = sweep_coefficients(fit_sweep(other, model.z_range), torch.stack([u, v], -1)).permute(2, 3, 0, 1)
        expected = sweep_match(full, s)[0]
    w = other.reference_width
    truth, covisible = capture.depth[..., :w], capture.covisible[..., :w]
    inner = torch.zeros_like(out.valid)
    inner[..., 8:-8, 8:-8] = True
    seen = inner & covisible
    sel = seen & out.valid
    assert float(sel.sum()) >= 0.9 * float(seen.sum())
    assert float(((out.depth - truth).abs() / truth)[sel].median()) < 1e-3
    assert float((out.match.double() - expected).norm(dim=1, keepdim=True)[sel].median()) < 0.05
