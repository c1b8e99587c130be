import pytest
import torch

from prismstereo import OptionError, RigError, ShapeError, thesis_setup1, thesis_setup2
from prismstereo.model import PrismStereo, hypotheses_for_rig
from prismstereo.synthetic import ImageFormation, fronto_parallel_plane, render, step_scene
from tests.conftest import scaled_rig


@pytest.fixture(scope="module")
def setup1_model():
    rig = scaled_rig(thesis_setup1(), 4)
    return rig, PrismStereo(rig, (400.0, 800.0))


def test_hypotheses_are_at_most_one_pixel_apart():
    rig = scaled_rig(thesis_setup1(), 4)
    depths = hypotheses_for_rig(rig, (400.0, 800.0))
    from prismstereo.epipolar import exact_sampling_grid

    grid = exact_sampling_grid(rig, depths, rows=torch.arange(0.0, rig.image_height, 8.0))
    ok = grid.valid[1:] & grid.valid[:-1]
    assert (grid.uv[1:] - grid.uv[:-1]).norm(dim=-1)[ok].max() <= 1.0
    with pytest.raises(RigError, match="z_range_mm must lie beyond"):
        hypotheses_for_rig(rig, (100.0, 800.0))


@pytest.mark.parametrize("depth", [450.0, 700.0])
def test_fronto_parallel_plane_depth(setup1_model, depth):
    rig, model = setup1_model
    cap = render(rig, fronto_parallel_plane(rig, depth, seed=5), ImageFormation(supersample=2, noise_sigma=1 / 255))
    with torch.no_grad():
        res = model(cap.image)
    w = rig.reference_width
    assert res.depth.shape == (1, 1, rig.image_height, w)
    cov = cap.covisible[..., :w]
    ok = res.valid & cov
    assert ok.float().sum() / cov.float().sum() > 0.95
    rel = ((res.depth - depth).abs() / depth)[ok]
    # quarter-resolution sensor: the error scales with the pixel size (0.25 % is the full-size target)
    assert rel.mean() < 0.006 and rel.median() < 0.004


def test_setup2_and_step_scene():
    rig = scaled_rig(thesis_setup2(), 4)
    model = PrismStereo(rig, (400.0, 700.0))
    cap = render(rig, step_scene(rig, 450.0, 650.0, seed=2), ImageFormation(supersample=2))
    with torch.no_grad():
        res = model(cap.image)
    w = rig.reference_width
    ok = res.valid & cap.covisible[..., :w]
    rel = ((res.depth - cap.depth[..., :w]).abs() / cap.depth[..., :w])[ok]
    assert rel.median() < 0.004 and (rel < 0.02).float().mean() > 0.9


def test_model_buffers_and_errors(setup1_model):
    rig, model = setup1_model
    assert model.grid.shape == (model.num_hypotheses, rig.image_height, rig.reference_width, 2)
    assert "grid" in dict(model.named_buffers())
    with pytest.raises(ShapeError, match="but the rig's sensor is"):
        model(torch.rand(1, 1, 10, 10))
    with pytest.raises(OptionError, match="num_hypotheses must be an int >= 2"):
        PrismStereo(rig, (400.0, 800.0), num_hypotheses=1)


def test_occlusion_test_rejects_pixels_hidden_from_the_right_half():
    rig = scaled_rig(thesis_setup1(), 4)
    cap = render(rig, step_scene(rig, 450.0, 650.0, seed=1), ImageFormation(supersample=2, noise_sigma=1 / 255))
    w = rig.reference_width
    hidden = cap.valid[..., :w] & ~cap.covisible[..., :w]
    cov = cap.covisible[..., :w]
    with torch.no_grad():
        plain = PrismStereo(rig, (400.0, 700.0), occlusion_tolerance=None)(cap.image)
        checked = PrismStereo(rig, (400.0, 700.0))(cap.image)
    assert checked.valid[hidden].float().mean() < 0.6 * plain.valid[hidden].float().mean()
    assert checked.valid[cov].float().mean() > 0.85
    rel = lambda r: ((r.depth - cap.depth[..., :w]).abs() / cap.depth[..., :w])  # noqa: E731
    bad = lambda r: ((rel(r) > 0.02) & r.valid).float().sum() / r.valid.float().sum()  # noqa: E731
    assert bad(checked) < bad(plain)
