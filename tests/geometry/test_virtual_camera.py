import math

import pytest
import torch

from prismstereo import OptionError, RigError, ShapeError, thesis_setup1, thesis_setup2
from prismstereo.geometry import (
    apex_ray,
    closest_point_to_rays,
    pinhole_reprojection_error,
    points_at_depth,
    ray_midpoint,
    trace_pixels,
    virtual_camera,
    virtual_cameras,
)

F64 = torch.float64
METHODS = ("two_point", "least_squares")


@pytest.fixture(scope="module")
def setup1_cameras():
    rig = thesis_setup1()
    return {m: virtual_cameras(rig, m) for m in METHODS}


def test_ray_midpoint_reference():
    o1, d1 = torch.tensor([0.0, 0.0, 0.0]), torch.tensor([1.0, 0.0, 0.0])
    o2, d2 = torch.tensor([3.0, 1.0, 2.0]), torch.tensor([0.0, 0.0, 1.0])
    torch.testing.assert_close(ray_midpoint(o1, d1, o2, d2), torch.tensor([3.0, 0.5, 0.0]))
    # batched, and intersecting lines give their intersection
    o = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    d = torch.tensor([[1.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    out = ray_midpoint(o, d, torch.tensor([[2.0, 0.0, 0.0]] * 2), torch.tensor([[0.0, 1.0, 0.0]] * 2))
    torch.testing.assert_close(out, torch.tensor([[2.0, 2.0, 0.0], [1.5, 1.0, 0.0]]))
    with pytest.raises(ShapeError, match="origin1 must have shape"):
        ray_midpoint(torch.zeros(2), d1, o2, d2)


def test_closest_point_to_rays_reference():
    gen = torch.Generator().manual_seed(4)
    centre = torch.tensor([1.0, -2.0, 3.0], dtype=F64)
    d = torch.randn(50, 3, generator=gen, dtype=F64)
    d = d / d.norm(dim=-1, keepdim=True)
    o = centre + d * torch.randn(50, 1, generator=gen, dtype=F64)  # every line passes through the centre
    torch.testing.assert_close(closest_point_to_rays(o, d), centre)
    # two lines: the least-squares point is the midpoint of their common perpendicular
    o2 = torch.tensor([[0.0, 0.0, 0.0], [3.0, 1.0, 2.0]], dtype=F64)
    d2 = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=F64)
    torch.testing.assert_close(closest_point_to_rays(o2, d2), ray_midpoint(o2[0], d2[0], o2[1], d2[1]))
    with pytest.raises(ShapeError, match="directions must have shape"):
        closest_point_to_rays(o2, d2[:, :2])


@pytest.mark.parametrize("method", METHODS)
def test_setup1_thesis_references(setup1_cameras, method):
    left, right = setup1_cameras[method]
    # beta = 0.0538 rad (thesis 3.3.2); ours is positive for the left half (see module docstring). The
    # least-squares orientation is fitted to all rays, so it may differ from the apex ray's by a little.
    tol = 5e-5 if method == "two_point" else 3e-4
    assert left.beta.item() == pytest.approx(0.0538, abs=tol)
    assert right.beta.item() == pytest.approx(-0.0538, abs=tol)
    # |OC_x| between 9.1 and 9.3 mm (thesis: 9.167 two-point, 9.2345 mean over all pixels)
    assert 9.1 < -left.centre[0].item() < 9.3
    assert 9.1 < right.centre[0].item() < 9.3
    assert abs(left.centre[1].item()) < 1e-2
    # focal length: the thesis finds f_vc ~ f (it quotes 24.4 mm); the exact model gives 25.06-25.12 mm
    assert left.focal_length_mm.item() == pytest.approx(25.0, abs=0.15)


def test_setup1_two_point_matches_thesis_closely(setup1_cameras):
    left = setup1_cameras["two_point"].left
    assert left.centre[0].item() == pytest.approx(-9.167, abs=0.01)  # thesis 9.167 mm (its sign convention)
    assert left.beta.item() == pytest.approx(0.05376, abs=1e-5)


@pytest.mark.parametrize("method", METHODS)
def test_mirror_symmetry_when_centred(setup1_cameras, method):
    left, right = setup1_cameras[method]
    mirror = torch.tensor([-1.0, 1.0, 1.0], dtype=F64)
    torch.testing.assert_close(right.centre[[0, 2]], (left.centre * mirror)[[0, 2]], atol=1e-9, rtol=0)
    torch.testing.assert_close(right.beta, -left.beta, atol=1e-9, rtol=0)
    torch.testing.assert_close(right.focal_length_mm, left.focal_length_mm, atol=1e-9, rtol=0)
    torch.testing.assert_close(right.reprojection_error_max_px, left.reprojection_error_max_px, atol=1e-6, rtol=0)


def test_offset_prism_breaks_symmetry_and_follows_eq_5_27_to_5_33():
    d = 3.0
    rig = thesis_setup1().replace(prism_offset_x_mm=d)
    a, n, t_o = rig.alpha_rad, rig.refractive_index, rig.apex_distance_mm
    w0 = math.atan(d / t_o)  # eq. 5.27
    mu3 = math.asin(n * math.sin(a - math.asin(math.sin(a - w0) / n)))  # eq. 5.28, 5.30 (our left half)
    mu4 = math.asin(n * math.sin(math.asin(math.sin(a + w0) / n) - a))  # eq. 5.29, 5.31 (our right half)
    for method in METHODS:
        left, right = virtual_cameras(rig, method)
        assert abs(left.beta.item() + right.beta.item()) > 0.03  # no longer mirror images
        assert abs(left.centre[0].item() + right.centre[0].item()) > 0.01 or method == "two_point"
        if method == "two_point":  # orientation is the apex ray's
            assert left.beta.item() == pytest.approx(mu3, abs=1e-12)
            assert right.beta.item() == pytest.approx(mu4, abs=1e-12)
        else:
            assert left.beta.item() == pytest.approx(mu3, abs=2e-3)
            assert right.beta.item() == pytest.approx(mu4, abs=2e-3)
    # the common FOV angle gamma = mu3 - mu4 (signed) barely changes (thesis sec. 5.5, prediction 3)
    gamma0 = 2 * math.asin(n * math.sin(a - math.asin(math.sin(a) / n)))  # eq. 5.10
    assert mu3 - mu4 == pytest.approx(gamma0, rel=1e-3)


def test_least_squares_beats_two_point(setup1_cameras):
    two, lsq = setup1_cameras["two_point"].left, setup1_cameras["least_squares"].left
    assert lsq.noncentrality_rms_mm < two.noncentrality_rms_mm
    assert lsq.reprojection_error_mean_px < two.reprojection_error_mean_px
    assert lsq.reprojection_error_max_px < two.reprojection_error_max_px


def test_setup1_measured_pinhole_limits(setup1_cameras):
    # the rays do not meet in one point: non-centrality ~0.14 mm; the best pinhole is off by ~0.4 px mean
    lsq = setup1_cameras["least_squares"].left
    assert 0.10 < lsq.noncentrality_max_mm.item() < 0.18
    assert 0.03 < lsq.noncentrality_rms_mm.item() < 0.09
    assert 0.25 < lsq.reprojection_error_mean_px.item() < 0.6
    assert 1.0 < lsq.reprojection_error_max_px.item() < 2.5


def test_setup2_pinhole_is_much_worse():
    lsq = virtual_camera(thesis_setup2(), "left")
    assert lsq.beta.item() == pytest.approx(0.196, abs=0.01)
    assert lsq.reprojection_error_mean_px.item() > 2.0 and lsq.reprojection_error_max_px.item() > 10.0
    assert lsq.noncentrality_max_mm.item() > 2.0


def test_kornia_camera_is_consistent(setup1_cameras):
    vc = setup1_cameras["least_squares"].left
    cam = vc.camera
    assert cam.intrinsics.shape == (1, 4, 4) and cam.extrinsics.shape == (1, 4, 4)
    assert cam.intrinsics.dtype == F64
    # the optical centre is the camera centre: extrinsics map it to the origin
    c = cam.extrinsics[0, :3, :3] @ vc.centre + cam.extrinsics[0, :3, 3]
    torch.testing.assert_close(c, torch.zeros(3, dtype=F64), atol=1e-12, rtol=0)
    # a point on the optical axis projects to the principal point
    axis_point = vc.centre + 500.0 * vc.rotation[:, 2]
    uv = cam.project(axis_point[None])
    torch.testing.assert_close(uv[0], torch.stack([cam.cx[0], cam.cy[0]]), atol=1e-9, rtol=0)
    # rotation is orthonormal
    torch.testing.assert_close(vc.rotation.T @ vc.rotation, torch.eye(3, dtype=F64), atol=1e-12, rtol=0)


def test_reprojection_error_is_measured_not_assumed():
    rig = thesis_setup1()
    vc = virtual_camera(rig, "left")
    # independent recomputation on other samples: points of random left pixels at 400 mm
    gen = torch.Generator().manual_seed(5)
    uv = torch.rand(400, 2, generator=gen, dtype=F64) * torch.tensor([500.0, 767.0], dtype=F64)
    pts = points_at_depth(trace_pixels(rig, uv), 400.0)
    err = (vc.camera.project(pts) - uv).norm(dim=-1)
    assert err.max() < vc.reprojection_error_max_px + 0.2
    assert err.mean() > 0.05  # the pinhole really is approximate
    mean, worst = pinhole_reprojection_error(rig, vc.camera, "left", (400.0, 401.0))
    assert 0.05 < mean < worst < vc.reprojection_error_max_px + 0.2


def test_two_point_custom_pixels():
    rig = thesis_setup1()
    pixels = torch.tensor([[383.5, 287.5], [383.5, 479.5]], dtype=F64)
    vc = virtual_camera(rig, "left", "two_point", pixels=pixels)
    # independent: midpoint of the two traced rays
    rays = trace_pixels(rig, pixels)
    expected = ray_midpoint(rays.origins[0], rays.directions[0], rays.origins[1], rays.directions[1])
    torch.testing.assert_close(vc.centre, expected)
    torch.testing.assert_close(vc.rotation[:, 2], apex_ray(rig, "left").directions)


def test_bad_arguments():
    rig = thesis_setup1()
    with pytest.raises(OptionError, match="Unknown method 'dlt'. Choose from: 'two_point', 'least_squares'"):
        virtual_camera(rig, "left", "dlt")
    with pytest.raises(OptionError, match="Unknown half 'both'"):
        virtual_camera(rig, "both")
    with pytest.raises(RigError, match="must all see through the left face"):
        virtual_camera(rig, "left", "two_point", pixels=torch.tensor([[900.0, 300.0], [800.0, 400.0]]))
    with pytest.raises(ShapeError, match=r"pixels must have shape \(2, 2\)"):
        virtual_camera(rig, "left", "two_point", pixels=torch.zeros(3, 2))
    with pytest.raises(RigError, match="depth_range_mm must satisfy"):
        virtual_camera(rig, "left", depth_range_mm=(100.0, 1000.0))
    with pytest.raises(RigError, match="depth_range_mm must satisfy"):
        virtual_camera(rig, "left", depth_range_mm=(900.0, 300.0))
    with pytest.raises(RigError, match="fewer than 8 valid grid pixels"):
        virtual_camera(rig, "left", grid_step=800)
