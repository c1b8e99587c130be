import pytest
import torch
import torch.nn.functional as F

from prismstereo import RigError, thesis_setup1, thesis_setup2
from prismstereo.analysis.pinhole_rectify import full_image_grid, rectification_residual, rectify_virtual_cameras
from prismstereo.geometry import virtual_cameras

F64 = torch.float64


@pytest.fixture(scope="module")
def setup1():
    rig = thesis_setup1()
    cams = virtual_cameras(rig)
    return rig, cams, rectify_virtual_cameras(rig, cams)


def _apply(h, uv):
    q = torch.cat([uv, torch.ones_like(uv[..., :1])], -1) @ h.T
    return q[..., :2] / q[..., 2:]


def test_rectified_pinhole_projections_share_rows(setup1):
    rig, cams, rect = setup1
    assert rect.left_grid.shape == (rig.image_height, rig.reference_width, 2)
    assert rect.baseline_mm == pytest.approx(float((cams.right.centre - cams.left.centre).norm()))
    # for the pinhole model itself, rectification is exact: projections of any point land on one row
    gen = torch.Generator().manual_seed(0)
    x = torch.rand(200, 3, generator=gen, dtype=F64) * torch.tensor([60.0, 60.0, 1000.0], dtype=F64)
    x = x + torch.tensor([-30.0, -30.0, 300.0], dtype=F64)
    left = _apply(rect.homography_left, cams.left.camera.project(x))
    right = _apply(rect.homography_right, cams.right.camera.project(x))
    assert (left[:, 1] - right[:, 1]).abs().max() < 1e-9
    # and the rotation is orthonormal with x along the baseline
    torch.testing.assert_close(rect.rotation.T @ rect.rotation, torch.eye(3, dtype=F64))
    torch.testing.assert_close(rect.rotation[:, 0], (cams.right.centre - cams.left.centre) / rect.baseline_mm)


def test_grids_invert_the_homographies(setup1):
    rig, _, rect = setup1
    v, u = 100, 200
    torch.testing.assert_close(_apply(rect.homography_left, rect.left_grid[v, u]), torch.tensor([u, v], dtype=F64))
    torch.testing.assert_close(_apply(rect.homography_right, rect.right_grid[v, u]), torch.tensor([u, v], dtype=F64))
    # the halves' centres land near the rectified image centre; each grid samples its own half
    assert (rect.left_grid[..., 0] < rig.apex_column + 20).float().mean() > 0.95
    assert (rect.right_grid[..., 0] > rig.apex_column - 20).float().mean() > 0.95
    img = torch.rand(1, 1, rig.image_height, rig.image_width, dtype=F64)
    out = F.grid_sample(img, full_image_grid(rect.left_grid, rig)[None], align_corners=False)
    assert out.shape == (1, 1, rig.image_height, rig.reference_width)


def test_residual_misalignment_is_measured(setup1):
    rig, _, rect = setup1
    depths = torch.tensor([228.0, 500.0, 1374.0], dtype=F64)
    res = rectification_residual(rig, rect, depths)
    assert res.mean_px.shape == (3,)
    # true correspondences are not row-aligned: ~0.1-0.3 px mean, up to ~0.85 px for setup 1
    assert (res.mean_px > 0.05).all() and (res.max_px < 1.5).all() and (res.max_px > 0.3).all()
    res2 = rectification_residual(thesis_setup2(), rectify_virtual_cameras(thesis_setup2()), depths)
    assert (res2.max_px > 1.5).all()  # far worse for the strongly distorting setup 2
    with pytest.raises(RigError, match="no exact correspondence"):
        rectification_residual(rig, rect, torch.tensor([176.0], dtype=F64), grid_step=512)
