import pytest
import torch
import torch.nn.functional as F

from prismstereo import OptionError, RigError, thesis_setup1, thesis_setup2
from prismstereo.epipolar import (
    band_residual,
    bands_for_tolerance,
    depth_hypotheses,
    exact_sampling_grid,
    normalise_right_grid,
    shift_bands,
)
from prismstereo.geometry import points_at_depth, project_points, trace_pixels
from tests.conftest import scaled_rig

F64 = torch.float64


def test_depth_hypotheses():
    d = depth_hypotheses(250.0, 1000.0, 4)
    step = (1 / 250 - 1 / 1000) / 3
    torch.testing.assert_close(1 / d, torch.tensor([1 / 250 - k * step for k in range(4)], dtype=F64))
    torch.testing.assert_close(depth_hypotheses(100.0, 400.0, 4, "linear"), torch.tensor([100.0, 200.0, 300.0, 400.0],
                                                                                          dtype=F64))
    with pytest.raises(OptionError, match="Unknown spacing 'log'"):
        depth_hypotheses(100.0, 400.0, 4, "log")
    with pytest.raises(RigError, match="0 < z_min < z_max"):
        depth_hypotheses(400.0, 100.0, 4)


def test_normalised_grid_addresses_the_right_half_crop():
    rig = scaled_rig(thesis_setup1())  # 128 x 96, W_ref = 64
    w_ref = rig.reference_width
    img = torch.arange(rig.image_height * rig.image_width, dtype=F64).view(1, 1, rig.image_height, rig.image_width)
    right = img[..., w_ref:]
    uv = torch.tensor([[[w_ref + 3.0, 5.0], [rig.image_width - 1.0, 0.0]]], dtype=F64)
    out = F.grid_sample(right, normalise_right_grid(uv, rig)[None], align_corners=False)
    torch.testing.assert_close(out[0, 0, 0], torch.stack([img[0, 0, 5, w_ref + 3], img[0, 0, 0, -1]]))


@pytest.mark.parametrize("make", [thesis_setup1, thesis_setup2])
def test_exact_grid_hits_true_matches(make):
    rig = scaled_rig(make())
    depths = depth_hypotheses(228.0, 1374.0, 12)
    grid = exact_sampling_grid(rig, depths)
    h, w_ref = rig.image_height, rig.reference_width
    assert grid.uv.shape == (12, h, w_ref, 2) and grid.valid.shape == (12, h, w_ref)
    assert grid.valid.float().mean() > 0.4
    # independent: project each hypothesis from scratch (no warm start)
    v, u = torch.meshgrid(torch.arange(h, dtype=F64), torch.arange(w_ref, dtype=F64), indexing="ij")
    rays = trace_pixels(rig, torch.stack([u, v], -1))
    for i in (0, 5, 11):
        proj = project_points(rig, points_at_depth(rays, depths[i]), "right", iterations=8)
        ok = grid.valid[i]
        assert torch.equal(ok, proj.valid & rays.valid & rays.left)
        assert (grid.uv[i][ok] - proj.uv[ok]).norm(dim=-1).max() < 0.01
        assert (grid.uv[i][ok] - proj.uv[ok]).norm(dim=-1).max() < 1e-9  # in fact to rounding


def test_exact_grid_rows_subset_and_gradients():
    rig = scaled_rig(thesis_setup1())
    p = rig.parameters(dtype=F64, requires_grad=True)
    depths = depth_hypotheses(300.0, 900.0, 3)
    grid = exact_sampling_grid(p, depths, rows=torch.tensor([10.0, 40.0]))
    assert grid.uv.shape == (3, 2, rig.reference_width, 2)
    grid.uv[grid.valid].sum().backward()
    for name in ("alpha", "n", "T", "T_o", "f", "d", "tilt"):
        g = getattr(p, name).grad
        assert g is not None and torch.isfinite(g).all() and g.abs().sum() > 0, name


@pytest.mark.parametrize("make,bands", [(thesis_setup1, 8), (thesis_setup2, 16)])
def test_shift_bands_structure(make, bands):
    rig = scaled_rig(make())
    depths = depth_hypotheses(228.0, 1374.0, 48)
    exact = exact_sampling_grid(rig, depths)
    sb = shift_bands(rig, depths, bands, exact=exact)
    assert sb.maps.shape[0] == bands and sb.maps.shape[1] == rig.image_height
    assert sb.band_of.tolist() == sorted(sb.band_of.tolist()) and sb.band_of.unique().numel() == bands
    # in sensor coordinates the right-half position moves right as depth grows (toward the ray's point at
    # infinity): shifts increase with the hypothesis index, and are 0 at each band's centre
    for b in range(bands):
        s = sb.shifts[sb.band_of == b]
        assert (s[1:] > s[:-1]).all() and (s == 0).sum() == 1
    res = band_residual(exact, sb)
    assert res.max_px >= max(res.max_horizontal_px, res.max_vertical_px) and res.mean_px < res.max_px


@pytest.mark.parametrize("make", [thesis_setup1, thesis_setup2])
def test_fast_form_within_0_05_px_over_the_working_range(make):
    rig = scaled_rig(make(), scale=4)
    depths = depth_hypotheses(228.0, 1374.0, 48)  # ~1 px apart at this resolution
    # every 12th row (16 rows, top to bottom) keeps the test fast: the residual varies smoothly over the rows,
    # its maximum over them is that of every 6th row within 2e-5 px for both setups
    rows = torch.arange(0.0, rig.image_height, 12.0)
    sb, res = bands_for_tolerance(rig, depths, tolerance_px=0.05, rows=rows)
    assert res.max_px < 0.05
    # and the residual shrinks as bands are added (more bands, less residual)
    exact = exact_sampling_grid(rig, depths, rows)
    coarse = band_residual(exact, shift_bands(rig, depths, 1, rows, exact))
    assert coarse.max_px > res.max_px


def test_band_errors():
    rig = scaled_rig(thesis_setup1())
    depths = depth_hypotheses(300.0, 900.0, 4)
    with pytest.raises(OptionError, match=r"bands must be an int in \[1, D=4\]"):
        shift_bands(rig, depths, 5)
    exact = exact_sampling_grid(rig, depths)
    other = shift_bands(rig, depth_hypotheses(300.0, 900.0, 3), 1)
    with pytest.raises(RigError, match="same hypotheses"):
        band_residual(exact, other)
    with pytest.raises(RigError, match="no band count up to 1"):
        bands_for_tolerance(rig, depth_hypotheses(228.0, 1374.0, 16), tolerance_px=1e-6, max_bands=1)
