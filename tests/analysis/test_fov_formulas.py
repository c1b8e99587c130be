"""The closed forms of thesis ch. 5 against Table 5.3 and against their own definitions."""

import math

import pytest
import torch

from prismstereo.analysis import (
    AnalysisError,
    boundary_angles,
    common_fov_angle,
    fov_coefficient,
    fov_type,
    ray1_angle,
    ray1_intercept,
    ray2_angle,
    ray2_intercept,
)

F64 = torch.float64
N, F = 1.48, 25.0
A1, A2 = math.radians(6.4), math.radians(21.8)


def sig4(x: float) -> float:
    return float(f"{x:.4g}")


# ----------------------------------------------------------------------------- Table 5.3 reference values
@pytest.mark.parametrize("alpha,phi2,h", [(A1, 0.05376, 0.20375), (A2, 0.18834, 2.55045)])
def test_ray1_reference_values(alpha, phi2, h):
    assert sig4(float(ray1_angle(alpha, N))) == sig4(phi2)
    assert sig4(float(ray1_intercept(alpha, N, 100.0))) == sig4(h)  # eq. 5.16, b = 100 mm
    assert float(common_fov_angle(alpha, N)) == pytest.approx(2 * phi2, rel=1e-4)  # eq. 5.10


@pytest.mark.parametrize(
    "alpha,sensor,phi4",
    [(A1, 4.7616, 0.04053), (A2, 4.7616, -0.09785), (A1, 6.3984, 0.07245), (A2, 6.3984, -0.06772)],
)
def test_ray2_angle_reference_values(alpha, sensor, phi4):
    assert sig4(float(ray2_angle(alpha, N, sensor, F))) == sig4(phi4)


def test_boundary_angles_reference_values():
    b = boundary_angles(N, 4.7616, F)
    assert round(math.degrees(b.alpha1), 2) == 5.62 and round(math.degrees(b.alpha2), 2) == 11.07
    # definitions: phi4 = phi2 at alpha1, phi4 = 0 at alpha2
    assert float(ray2_angle(b.alpha1, N, 4.7616, F) - ray1_angle(b.alpha1, N)) == pytest.approx(0, abs=1e-12)
    assert float(ray2_angle(b.alpha2, N, 4.7616, F)) == pytest.approx(0, abs=1e-12)
    # the wider sensor pushes both boundaries up (gamma does not depend on it, phi4 does)
    wide = boundary_angles(N, 6.3984, F)
    assert wide.alpha1 > b.alpha1 and wide.alpha2 > b.alpha2


def test_table_5_3_v_is_eq_5_25_with_one_apex_distance_per_prism():
    # The thesis does not state T_o for Table 5.3; v is linear in T_o, so fit it on the narrow sensor and
    # predict the wide sensor's v: eq. 5.25 must reproduce both with the same T_o.
    table = ((A1, 5.6, 19.39945, 26.16954), (A2, 50 * math.tan(A2), 18.07693, 25.30311))
    for alpha, thickness, v_narrow, v_wide in table:
        v0 = float(ray2_intercept(alpha, N, 4.7616, F, thickness, 1e-9))
        v1 = float(ray2_intercept(alpha, N, 4.7616, F, thickness, 1.0))
        t_o = (v_narrow - v0) / (v1 - v0)
        assert 150 < t_o < 250
        assert sig4(float(ray2_intercept(alpha, N, 6.3984, F, thickness, t_o))) == sig4(v_wide)


# ----------------------------------------------------------------------------- FOV type (Table 5.1)
def test_fov_type_switches_at_alpha1_and_alpha2():
    b = boundary_angles(N, 4.7616, F)
    eps = 1e-7
    assert fov_type(b.alpha1 * (1 - eps), N, 4.7616, F) == "divergent"
    assert fov_type(b.alpha1 * (1 + eps), N, 4.7616, F) == "semi-divergent"
    assert fov_type(b.alpha2 * (1 - eps), N, 4.7616, F) == "semi-divergent"
    assert fov_type(b.alpha2 * (1 + eps), N, 4.7616, F) == "convergent"
    assert float(fov_coefficient(b.alpha1 * (1 - eps), N, 4.7616, F)) > 1 > float(
        fov_coefficient(b.alpha1 * (1 + eps), N, 4.7616, F))


def test_thesis_setups_types():
    # Table 5.3's set-ups: 1 semi-divergent (the thesis calls it divergent), 3 divergent, 2 and 4 convergent
    assert fov_type(A1, N, 4.7616, F) == "semi-divergent"
    assert fov_type(A1, N, 6.3984, F) == "divergent"
    assert fov_type(A2, N, 4.7616, F) == fov_type(A2, N, 6.3984, F) == "convergent"


# ----------------------------------------------------------------------------- dtype, gradients, invalid input
def test_ray1_angle_keeps_the_dtype_and_is_differentiable():
    out = ray1_angle(torch.tensor([A1], dtype=torch.float32), torch.tensor(N))
    assert out.dtype == torch.float32
    alpha = torch.tensor(A1, dtype=F64, requires_grad=True)
    (g,) = torch.autograd.grad(ray1_angle(alpha, N), alpha)
    assert 0.45 < float(g) < 0.5  # ~ n - 1 for a thin prism


def test_invalid_parameters_raise():
    with pytest.raises(AnalysisError, match="alpha must be in"):
        ray1_angle(0.0, N)
    with pytest.raises(AnalysisError, match="alpha must be in"):
        ray2_angle(math.pi, N, 4.7616, F)
    with pytest.raises(AnalysisError, match="refractive_index - 1 must be"):
        ray1_angle(A1, 0.9)
    with pytest.raises(AnalysisError, match="totally internally reflected"):
        ray1_angle(math.radians(86.0), N)
    with pytest.raises(AnalysisError, match="sensor_width_mm must be"):
        ray2_angle(A1, N, -1.0, F)
    with pytest.raises(AnalysisError, match="n must be > 1"):
        boundary_angles(1.0, 4.7616, F)
    with pytest.raises(AnalysisError, match="focal_length_mm must be a positive number"):
        boundary_angles(N, 4.7616, 0.0)
