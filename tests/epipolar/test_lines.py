import pytest
import torch

from prismstereo import RigError, ShapeError, thesis_setup1, thesis_setup2
from prismstereo.epipolar import (
    epipolar_line_accuracy,
    exact_epipolar_curve,
    exact_infinity_point,
    fundamental_epipolar_lines,
    fundamental_matrix,
    point_line_distance,
    projection_matrix,
    thesis_epipolar_lines,
)
from prismstereo.geometry import points_at_depth, project_points, trace_pixels, virtual_cameras
from prismstereo.synthetic import ImageFormation, render, sphere_scene

F64 = torch.float64


@pytest.fixture(scope="module")
def setup1():
    rig = thesis_setup1()
    return rig, virtual_cameras(rig)


def centre_pixels(rig, n=50, seed=0, spread=40.0):
    gen = torch.Generator().manual_seed(seed)
    centre = torch.tensor([rig.apex_column / 2, rig.cy], dtype=F64)
    return centre + (torch.rand(n, 2, generator=gen, dtype=F64) - 0.5) * 2 * spread


def test_projection_matrix_projects_like_kornia(setup1):
    rig, cams = setup1
    p = projection_matrix(cams.right)
    x = torch.tensor([[10.0, -5.0, 600.0], [-30.0, 20.0, 900.0]], dtype=F64)
    q = torch.cat([x, torch.ones(2, 1, dtype=F64)], 1) @ p.T
    torch.testing.assert_close(q[:, :2] / q[:, 2:], cams.right.camera.project(x))


def test_thesis_lines_pass_through_epipole_and_infinity_point(setup1):
    rig, cams = setup1
    uv = centre_pixels(rig)
    ep = thesis_epipolar_lines(rig, uv, cams)
    assert ep.lines.shape == (50, 3) and ep.infinity_points.shape == (50, 2) and ep.epipole.shape == (2,)
    torch.testing.assert_close(ep.lines[:, :2].norm(dim=-1), torch.ones(50, dtype=F64))
    assert point_line_distance(ep.epipole, ep.lines).max() < 1e-6
    assert point_line_distance(ep.infinity_points, ep.lines).max() < 1e-9


def test_thesis_and_fundamental_lines_agree_near_centre(setup1):
    # symmetric rig: near the image centre the two straight-line models agree to < 0.1 px
    rig, cams = setup1
    uv = centre_pixels(rig)
    thesis = thesis_epipolar_lines(rig, uv, cams).lines
    fund = fundamental_epipolar_lines(uv, fundamental_matrix(cams))
    curve = exact_epipolar_curve(rig, uv, torch.tensor([400.0, 600.0, 900.0], dtype=F64))
    assert curve.valid.all()
    for k in range(3):  # compare the lines where the correspondences actually are
        pts = curve.uv[:, k]
        signed = (pts * fund[:, :2]).sum(-1) + fund[:, 2]
        foot = pts - signed[:, None] * fund[:, :2]  # the point of the F-line nearest the true match
        assert point_line_distance(foot, thesis).max() < 0.1


def test_fundamental_matrix_constraint_on_pinhole_projections(setup1):
    rig, cams = setup1
    x = torch.tensor([[10.0, -5.0, 600.0], [-30.0, 20.0, 900.0], [5.0, 40.0, 400.0]], dtype=F64)
    a = torch.cat([cams.left.camera.project(x), torch.ones(3, 1, dtype=F64)], 1)
    b = torch.cat([cams.right.camera.project(x), torch.ones(3, 1, dtype=F64)], 1)
    f = fundamental_matrix(cams)
    residual = (b * (a @ f.T)).sum(-1) / (a @ f.T)[:, :2].norm(dim=-1)
    assert residual.abs().max() < 1e-6  # distance (px) of the right image from F x_left


def test_exact_curve_passes_through_rendered_correspondences():
    small = thesis_setup1().replace(image_width=256, image_height=192, pixel_size_mm=0.0186, principal_point=None)
    cap = render(small, sphere_scene(small, 450.0, 40.0, 650.0), ImageFormation(supersample=1, bits=None))
    cov = cap.covisible[0, 0]
    v, u = torch.nonzero(cov, as_tuple=True)
    sel = torch.arange(0, v.numel(), max(1, v.numel() // 300))
    uv = torch.stack([u[sel], v[sel]], dim=-1).to(F64)
    depth = cap.depth[0, 0][v[sel], u[sel]]
    match = cap.match_uv[0].permute(1, 2, 0)[v[sel], u[sel]]
    for i in range(0, len(sel), 60):
        curve = exact_epipolar_curve(small, uv[i:i + 1], depth[i:i + 1])
        assert (curve.uv[0, 0] - match[i]).norm() < 1e-6


def test_infinity_point_is_the_curve_asymptote(setup1):
    rig, cams = setup1
    uv = centre_pixels(rig, 20)
    inf = exact_infinity_point(rig, uv)
    far = exact_epipolar_curve(rig, uv, torch.tensor([1e6, 1e7], dtype=F64))
    assert inf.valid.all()
    assert (far.uv[:, 1] - inf.uv).norm(dim=-1).max() < 0.01
    assert (far.uv[:, 0] - inf.uv).norm(dim=-1).max() < 0.1
    # the thesis' pinhole infinity point (eq. 4.5-4.9) approximates it near the centre
    thesis = thesis_epipolar_lines(rig, uv, cams).infinity_points
    assert (thesis - inf.uv).norm(dim=-1).max() < 1.0


def test_exact_curve_shapes_and_validity(setup1):
    rig, _ = setup1
    uv = torch.tensor([[[100.0, 100.0], [300.0, 400.0]], [[900.0, 300.0], [5.0, 5.0]]], dtype=F64)
    curve = exact_epipolar_curve(rig, uv, torch.tensor([300.0, 600.0, 1200.0], dtype=F64))
    assert curve.uv.shape == (2, 2, 3, 2) and curve.valid.shape == (2, 2, 3)
    assert not curve.valid[1, 0].any()  # a right-half pixel has no curve in the right half
    with pytest.raises(ShapeError, match="depths must have shape"):
        exact_epipolar_curve(rig, uv, torch.ones(2, 2, dtype=F64))


def test_curve_gradients_reach_rig_parameters():
    rig = thesis_setup1()
    p = rig.parameters(dtype=F64, requires_grad=True)
    curve = exact_epipolar_curve(p, torch.tensor([[300.0, 200.0]], dtype=F64), torch.tensor([500.0], dtype=F64))
    curve.uv.sum().backward()
    for name in ("alpha", "n", "T", "T_o", "f", "d"):
        assert getattr(p, name).grad is not None and getattr(p, name).grad.abs() > 0, name


def test_line_accuracy_report():
    rig = thesis_setup1()
    full = epipolar_line_accuracy(rig, grid_step=64, depths=6)
    centre = epipolar_line_accuracy(rig, grid_step=16, depths=6, centre_fraction=0.2)
    assert full.samples > 100 and centre.samples > 20
    # straight lines are sub-pixel near the centre but not over the whole image
    assert centre.thesis_max_px < 0.3 and centre.fundamental_max_px < 0.3
    assert full.thesis_max_px > centre.thesis_max_px and full.fundamental_max_px > 0.5
    setup2 = epipolar_line_accuracy(thesis_setup2(), grid_step=64, depths=6)
    assert setup2.fundamental_max_px > 5.0 and setup2.pinhole_max_px > 10.0
    with pytest.raises(RigError, match="centre_fraction"):
        epipolar_line_accuracy(rig, centre_fraction=0.0)
    with pytest.raises(RigError, match="depth_range_mm"):
        epipolar_line_accuracy(rig, depth_range_mm=(100.0, 500.0))


def test_line_inputs_validated(setup1):
    rig, cams = setup1
    with pytest.raises(ShapeError, match="uv_ref must have shape"):
        thesis_epipolar_lines(rig, torch.zeros(3, 3, dtype=F64), cams)
    with pytest.raises(ShapeError, match="fundamental must have shape"):
        fundamental_epipolar_lines(torch.zeros(3, 2, dtype=F64), torch.eye(4, dtype=F64))
    rays = trace_pixels(rig, torch.tensor([[300.0, 200.0]], dtype=F64))
    assert project_points(rig, points_at_depth(rays, 500.0), "right").valid.all()
