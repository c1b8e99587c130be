import math

import pytest
import torch

from prismstereo import CalibrationError, thesis_setup1
from prismstereo.calibration.parameters import NAMES, rig_vector, vector_to_rig
from prismstereo.calibration.uncertainty import depth_uncertainty
from prismstereo.geometry.optics import points_at_depth, trace_pixels
from prismstereo.geometry.projection import project_points
from prismstereo.geometry.virtual_camera import ray_midpoint

F64 = torch.float64


@pytest.mark.parametrize("name", ["alpha_deg", "focal_length_mm", "apex_distance_mm"])
def test_depth_uncertainty_is_the_first_order_depth_change(name):
    """One parameter's variance alone: sigma_Z / Z equals the relative depth change of re-triangulating the same pixel
    pairs with that parameter moved by one sigma (finite difference through the exact optics)."""
    rig = thesis_setup1().downscaled(4)
    i = NAMES.index(name)
    sigma = {"alpha_deg": math.radians(0.05), "focal_length_mm": 0.05, "apex_distance_mm": 0.5}[name]
    cov = torch.zeros(16, 16, dtype=F64)
    cov[i, i] = sigma**2
    z = 600.0
    ours = float(depth_uncertainty(rig, cov, [z], grid=5).relative_std[0])
    u = torch.linspace(0.05, 0.95, 5, dtype=F64) * (rig.reference_width - 1)
    v = torch.linspace(0.05, 0.95, 5, dtype=F64) * (rig.image_height - 1)
    left = torch.stack(torch.meshgrid(u, v, indexing="xy"), -1).reshape(-1, 2)
    rays = trace_pixels(rig, left, "left")
    proj = project_points(rig, points_at_depth(rays, z), "right")
    ok = proj.valid
    moved = rig_vector(rig)
    h = 1e-3 * sigma
    moved[i] += h
    other = vector_to_rig(moved, rig)
    a, b = trace_pixels(other, left[ok], "left"), trace_pixels(other, proj.uv[ok], "right")
    dz = (ray_midpoint(a.origins, a.directions, b.origins, b.directions)[:, 2] - z) / h * sigma
    expected = float((dz / z).pow(2).mean().sqrt())
    assert ours == pytest.approx(expected, rel=1e-3)


def test_depth_uncertainty_zero_and_errors():
    rig = thesis_setup1().downscaled(4)
    out = depth_uncertainty(rig, torch.zeros(16, 16, dtype=F64), [500.0, 900.0])
    assert out.relative_std.tolist() == [0.0, 0.0] and (out.pixels > 10).all()
    with pytest.raises(CalibrationError, match=r"covariance must be \(16, 16\)"):
        depth_uncertainty(rig, torch.zeros(3, 3), [500.0])
    with pytest.raises(CalibrationError, match="no depth"):
        depth_uncertainty(rig, torch.zeros(16, 16), [])


def test_share_is_what_knowing_each_parameter_removes():
    """One uncertain parameter: knowing it removes all of the depth variance, the others nothing; two perfectly
    correlated ones: knowing either removes all of it."""
    rig = thesis_setup1().downscaled(4)
    alpha, t_o = NAMES.index("alpha_deg"), NAMES.index("apex_distance_mm")
    cov = torch.zeros(16, 16, dtype=torch.float64)
    cov[alpha, alpha] = 1e-6
    share = depth_uncertainty(rig, cov, [600.0], grid=5).share
    assert share.shape == (16,) and float(share[alpha]) == pytest.approx(1.0) and float(share.sum()) == pytest.approx(1)
    both = torch.zeros(16, 16, dtype=torch.float64)
    both[alpha, alpha], both[t_o, t_o], both[alpha, t_o] = 1e-6, 1.0, 1e-3
    both[t_o, alpha] = 1e-3
    share = depth_uncertainty(rig, both, [600.0], grid=5).share
    assert float(share[alpha]) == pytest.approx(1.0) and float(share[t_o]) == pytest.approx(1.0)
