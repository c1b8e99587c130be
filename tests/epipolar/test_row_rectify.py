import pytest
import torch

from prismstereo import OptionError, thesis_setup1, thesis_setup2
from prismstereo.analysis.pinhole_rectify import rectification_residual, rectify_virtual_cameras
from prismstereo.epipolar.row_rectify import fit_row_rectification, rectified_level, rectified_rows, source_rows
from prismstereo.epipolar.sweep import fit_sweep, sweep_positions
from prismstereo.geometry.optics import trace_pixels

F64 = torch.float64
Z_RANGE = (228.0, 1374.0)


@pytest.mark.parametrize("setup, bound", [(thesis_setup1, 1e-3), (thesis_setup2, 0.15)])
def test_correspondences_share_a_row(setup, bound):
    """The module's claim, on points the fit never saw: after the warps, a reference pixel and its exact
    correspondence at any depth are on the same row (setup 1 to 2e-4 px, setup 2 to ~0.1 px); the pinhole
    rectification of the virtual cameras leaves ~1 / 12 px."""
    rig = setup().downscaled(2)
    fit = fit_sweep(rig, Z_RANGE)
    rect = fit_row_rectification(rig, fit)
    assert rect.max_residual_px < bound and rect.rms_residual_px < bound / 4
    gen = torch.Generator().manual_seed(3)
    uv = torch.rand(600, 2, generator=gen, dtype=F64) * torch.tensor(
        [rig.reference_width - 1.0, rig.image_height - 1.0], dtype=F64)
    s = torch.rand(7, generator=gen, dtype=F64) * 2 - 1
    pos = sweep_positions(fit, uv, s.view(-1, 1)).transpose(0, 1)  # (600, 7, 2)
    rays = trace_pixels(rig, uv)
    ok = ((pos[..., 0] >= rig.reference_width) & (pos[..., 0] <= rig.image_width - 1) & (pos[..., 1] >= 0)
          & (pos[..., 1] <= rig.image_height - 1) & (rays.valid & rays.left).unsqueeze(1))
    assert ok.sum() > 1000
    r_ref = rectified_rows(rect, uv, "reference").unsqueeze(1).expand_as(ok)
    r_oth = rectified_rows(rect, pos, "other")
    residual = (r_ref - r_oth)[ok].abs()
    assert residual.max() < bound
    if setup is thesis_setup2:  # the pinhole rectification is far worse on the same rig
        pinhole = rectification_residual(rig, rectify_virtual_cameras(rig), torch.tensor([300.0, 1000.0], dtype=F64))
        assert pinhole.max_px.max() > 20 * residual.max()


def test_source_rows_inverts_and_centre_column_is_fixed():
    rig = thesis_setup1().downscaled(4)
    fit = fit_sweep(rig, (300.0, 900.0))
    rect = fit_row_rectification(rig, fit, degree=3)
    u = torch.tensor([0.0, 40.0, 127.0], dtype=F64)
    for side, cols in (("reference", u), ("other", u + rig.reference_width)):
        r = torch.tensor([-3.0, 50.0, 190.0], dtype=F64)
        v = source_rows(rect, cols, r, side)
        torch.testing.assert_close(rectified_rows(rect, torch.stack([cols, v], -1), side), r)
    centre = torch.tensor([[(rig.reference_width - 1) / 2, 17.0]], dtype=F64)
    torch.testing.assert_close(rectified_rows(rect, centre, "reference"), torch.tensor([17.0], dtype=F64))


def test_level_shifts_follow_the_sweep():
    """At a level, the rectified other pixel of shift k is the exact correspondence of the rectified reference
    pixel at the depth whose column is u + k f (checked through the grids themselves)."""
    rig = thesis_setup1().downscaled(4)
    fit = fit_sweep(rig, (300.0, 900.0))
    rect = fit_row_rectification(rig, fit)
    w_o = rig.image_width - rig.reference_width
    level = rectified_level(rect, fit, 2, torch.ones(rig.image_height, w_o, dtype=torch.bool))
    d, h_r, w_l = level.valid.shape
    assert level.index.shape == (d, w_l) and level.reference_grid.shape == (h_r, w_l, 2)
    assert torch.equal(level.shifts, torch.arange(level.shifts[0], level.shifts[-1] + 1, dtype=F64))
    assert 0.3 < level.valid.double().mean() < 0.9
    # a valid sample: reference source (u, v), other source (x, y) must satisfy the sweep at some s
    k, rc, uc = [int(t[len(t) // 2]) for t in level.valid.nonzero(as_tuple=True)]
    f, h_l = 2, -(-rig.image_height // 2)
    v = ((level.reference_grid[rc, uc, 1] + 1) * f * h_l / 2) - 0.5
    u = (uc + 0.5) * f - 0.5
    xc = int(level.index[k, uc])
    y = ((level.other_grid[rc, xc, 1] + 1) * f * h_l / 2) - 0.5
    x = (xc + 0.5) * f - 0.5 + rig.reference_width
    s = torch.linspace(-1, 1, 4001, dtype=F64)
    curve = sweep_positions(fit, torch.tensor([[u, float(v)]], dtype=F64), s.view(-1, 1))[:, 0]
    j = int((curve[:, 0] - x).abs().argmin())
    assert abs(float(curve[j, 1] - y)) < 0.01
    # the back grid sends every reference pixel into the rectified level
    assert level.back_grid.abs().max() <= 1.0


def test_errors():
    rig = thesis_setup1().downscaled(8)
    fit = fit_sweep(rig, (400.0, 900.0))
    with pytest.raises(OptionError, match="degree"):
        fit_row_rectification(rig, fit, degree=0)
    rect = fit_row_rectification(rig, fit)
    with pytest.raises(OptionError, match="side"):
        rectified_rows(rect, torch.zeros(1, 2, dtype=F64), "left")
    with pytest.raises(OptionError, match="factor"):
        rectified_level(rect, fit, 0, torch.ones(96, 64, dtype=torch.bool))
    with pytest.raises(OptionError, match="other_valid"):
        rectified_level(rect, fit, 1, torch.ones(10, 10, dtype=torch.bool))


def test_tiny_sensor_gets_a_denser_sample_grid():
    """On a 64 x 48 sensor the default 8 px grid would leave 4 x 6 sample positions for a degree-4 warp in
    (u, v): underdetermined, the least squares found warps moving rows by ~1500 px (the rectified level then
    had 2367 rows for a 48-row sensor). The default step shrinks there, and the warps stay small."""
    rig = thesis_setup1().downscaled(16)
    fit = fit_sweep(rig, (300.0, 900.0))
    rect = fit_row_rectification(rig, fit)
    uv = torch.stack(torch.meshgrid(torch.arange(rig.reference_width, dtype=F64),
                                    torch.arange(rig.image_height, dtype=F64), indexing="xy"), -1)
    assert (rectified_rows(rect, uv, "reference") - uv[..., 1]).abs().max() < 3.0
    assert rect.max_residual_px < 1e-3
    loose = fit_row_rectification(rig, fit, step=8)  # the old default: an exact fit of a useless warp
    assert (rectified_rows(loose, uv, "reference") - uv[..., 1]).abs().max() > 100
