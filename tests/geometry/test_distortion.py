import cv2
import numpy as np
import pytest
import torch

from prismstereo import RigError, ShapeError, thesis_setup1, thesis_setup2
from prismstereo.geometry.distortion import distort, distortion_jacobian, max_round_trip_px, undistort
from prismstereo.geometry.optics import pixel_directions, trace_pixels
from prismstereo.geometry.projection import project_points
from prismstereo.geometry.rig import BiPrismRig

F64 = torch.float64
# the calibration range (k1 in [-0.1, 0.05]) plus the other terms, and a strong lens
COEFFS = [(-0.1, 0.0, 0.0, 0.0, 0.0), (0.05, -0.02, 1e-3, -2e-3, 0.01), (-0.3, 0.1, -2e-3, 1e-3, -0.02)]


def _points(n=500, radius=0.3, seed=0):
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(n, 2, generator=g, dtype=F64) * 2 - 1) * radius


@pytest.mark.parametrize("k", COEFFS)
def test_distort_is_opencv_project_points(k):
    xy = _points()
    ours = distort(xy, torch.tensor(k, dtype=F64)).numpy()
    obj = np.concatenate([xy.numpy(), np.ones((len(xy), 1))], axis=1)
    cv, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), np.eye(3), np.array(k))
    np.testing.assert_allclose(ours, cv[:, 0], atol=1e-14)


@pytest.mark.parametrize("k", COEFFS)
def test_undistort_round_trip_and_opencv(k):
    xy_d = _points()
    coeffs = torch.tensor(k, dtype=F64)
    xy = undistort(xy_d, coeffs)
    assert (distort(xy, coeffs) - xy_d).abs().max() < 1e-15
    # OpenCV's fixed-point inverse, run long enough to converge, agrees
    cv = cv2.undistortPoints(xy_d.numpy()[:, None], np.eye(3), np.array(k), R=None, P=None,
                                 criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15))
    np.testing.assert_allclose(xy.numpy(), cv[:, 0], atol=1e-12)
    # float32 follows the input's dtype and stays accurate
    xy32 = undistort(xy_d.float(), coeffs.float())
    assert xy32.dtype == torch.float32 and (xy32.double() - xy).abs().max() < 1e-6


def test_zero_coefficients_are_the_identity_bit_for_bit():
    xy = _points(radius=0.5)
    zero = torch.zeros(5, dtype=F64)
    assert torch.equal(distort(xy, zero), xy) and torch.equal(undistort(xy, zero), xy)
    j = distortion_jacobian(xy, zero)
    assert torch.equal(j.xx, torch.ones(len(xy), dtype=F64)) and torch.equal(j.xy, torch.zeros(len(xy), dtype=F64))
    # a distortion-free rig keeps the pinhole formulas: no tensor, no iterations
    assert thesis_setup1().parameters().distortion is None
    assert thesis_setup1().parameters(requires_grad=True).distortion.shape == (5,)


def test_jacobian_matches_autograd():
    xy = _points(20).requires_grad_(True)
    k = torch.tensor(COEFFS[1], dtype=F64)
    jac = torch.autograd.functional.jacobian(lambda p: distort(p, k).sum(0), xy)  # (2, N, 2)
    j = distortion_jacobian(xy.detach(), k)
    assert torch.allclose(jac[0, :, 0], j.xx) and torch.allclose(jac[0, :, 1], j.xy)
    assert torch.allclose(jac[1, :, 0], j.yx) and torch.allclose(jac[1, :, 1], j.yy)


def test_undistort_gradcheck():
    xy = _points(6).requires_grad_(True)
    k = torch.tensor(COEFFS[2], dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(undistort, (xy, k), eps=1e-7, atol=1e-7)


def test_shape_errors():
    with pytest.raises(ShapeError, match="xy"):
        distort(torch.zeros(4, 3), torch.zeros(5))
    with pytest.raises(ShapeError, match="coefficients"):
        undistort(torch.zeros(4, 2), torch.zeros(4))
    with pytest.raises(TypeError, match="floating"):
        undistort(torch.zeros(4, 2, dtype=torch.long), torch.zeros(5))


def test_fold_over_is_detected():
    corners = torch.tensor([[0.5, 0.5], [-0.6, 0.3]], dtype=F64)
    assert max_round_trip_px(torch.tensor([-1.0, 0, 0, 0, 0], dtype=F64), corners, 1000.0) > 1.0  # no inverse
    assert max_round_trip_px(torch.tensor([-0.1, 0, 0, 0, 0], dtype=F64), corners, 1000.0) < 1e-9


# ----------------------------------------------------------------------------- the rig's lens
def test_rig_field_validation_and_json():
    rig = thesis_setup2().replace(distortion=[-0.1, 0.02, 1e-3, -1e-3, 0.0])
    assert rig.distortion == (-0.1, 0.02, 1e-3, -1e-3, 0.0) and rig.distorted
    assert BiPrismRig.from_json(rig.to_json()) == rig
    assert thesis_setup1().to_dict()["distortion"] == [0.0] * 5
    with pytest.raises(RigError, match="distortion must be a list of 5"):
        thesis_setup1().replace(distortion=(0.1, 0.0))
    with pytest.raises(RigError, match="not invertible over the sensor"):
        thesis_setup2().replace(distortion=(-5.0, 0.0, 0.0, 0.0, 0.0))


@pytest.mark.parametrize("base", [thesis_setup1, thesis_setup2])
@pytest.mark.parametrize("k", COEFFS[:2])
def test_trace_and_project_round_trip_with_distortion(base, k):
    rig = base().replace(distortion=k, prism_tilt_deg=(0.2, -0.3, 0.3), prism_offset_x_mm=0.4)
    g = torch.Generator().manual_seed(1)
    uv = torch.rand(3000, 2, generator=g, dtype=F64) * torch.tensor([rig.image_width - 1.0, rig.image_height - 1.0])
    rays = trace_pixels(rig, uv)
    for depth in (300.0, 1400.0):
        X = rays.origins + rays.directions * (depth - rays.origins[:, 2:]) / rays.directions[:, 2:]
        for half, mask in (("left", rays.left), ("right", ~rays.left)):
            m = mask & rays.valid
            proj = project_points(rig, X[m], half)
            assert proj.valid.float().mean() > 0.999
            assert (proj.uv - uv[m])[proj.valid].norm(dim=-1).max() < 1e-6


def test_distortion_bends_the_rays_like_opencv():
    k = COEFFS[1]
    rig = thesis_setup1().replace(distortion=k, principal_point=(500.0, 390.0))
    uv = torch.tensor([[10.0, 20.0], [1000.0, 700.0], [500.0, 390.0]], dtype=F64)
    d = pixel_directions(rig, uv)
    fpx = rig.focal_length_px
    kmat = np.array([[fpx, 0, 500.0], [0, fpx, 390.0], [0, 0, 1]])
    cv = cv2.undistortPoints(uv.numpy()[:, None], kmat, np.array(k), R=None, P=None,
                                 criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15))[:, 0]
    np.testing.assert_allclose((d[:, :2] / d[:, 2:]).numpy(), cv, atol=1e-12)


def test_rig_gradients_reach_the_distortion():
    rig = thesis_setup1().replace(distortion=COEFFS[0])
    p = rig.parameters(dtype=F64, requires_grad=True)
    X = torch.tensor([[-30.0, 20.0, 600.0], [-10.0, -40.0, 800.0]], dtype=F64)
    proj = project_points(p, X, "left")
    proj.uv.sum().backward()
    assert p.distortion.grad is not None and p.distortion.grad[0].abs() > 0

    def u_of_k(k):
        return project_points(p._replace(distortion=k), X, "left").uv

    k = p.distortion.detach().clone().requires_grad_(True)
    assert torch.autograd.gradcheck(u_of_k, (k,), eps=1e-7, atol=1e-5)


# ----------------------------------------------------------------------------- a rolled prism's split
def test_rolled_prism_split_holds_every_left_pixel():
    for roll in (0.3, -1.0):
        rig = thesis_setup1().replace(prism_tilt_deg=(0.0, 0.0, roll), distortion=COEFFS[0])
        w = rig.reference_width
        v, u = torch.meshgrid(torch.arange(rig.image_height, dtype=F64), torch.arange(rig.image_width, dtype=F64),
                              indexing="ij")
        rays = trace_pixels(rig, torch.stack([u, v], -1))
        cols = u[rays.left & rays.valid]
        assert cols.max() == w - 1  # every left-half pixel is in the crop, and the crop is no wider
    assert thesis_setup1().replace(prism_tilt_deg=(0.0, 0.0, 0.3)).reference_width == 514


def test_pixels_beyond_the_lens_fold_trace_invalid():
    """Projection solves over [-W, 2W]: where a strong lens model folds over, a pixel has no preimage and its ray
    comes back invalid instead of tracing a wrong preimage."""
    rig = thesis_setup2().replace(distortion=(-0.4, 0.0, 0.0, 0.0, 0.0))
    far = torch.tensor([[-1024.0, -768.0], [2048.0, 1536.0]], dtype=F64)
    assert not trace_pixels(rig, far).valid.any()
    assert trace_pixels(rig, torch.tensor([[100.0, 300.0], [900.0, 300.0]], dtype=F64)).valid.all()
