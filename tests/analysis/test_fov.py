"""FOV closed forms of thesis ch. 5 against Table 5.3 and against the exact ray-traced FOV."""

import math

import pytest
import torch

from prismstereo import OptionError, thesis_setup1, thesis_setup2
from prismstereo.analysis import (
    AnalysisError,
    boundary_angles,
    common_fov_angle,
    compare_fov,
    exact_fov_extent,
    exact_fov_type,
    fov_alpha_sweep,
    fov_closed_form,
    fov_coefficient,
    fov_extent,
    fov_type,
    offset_shift,
    ray1_angle,
    ray1_intercept,
    ray2_angle,
    ray2_intercept,
)
from prismstereo.geometry import apex_ray

F64 = torch.float64
N, F = 1.48, 25.0
SENSORS = {"CV-M9CL": 4.7616, "CB-140MCL": 6.3984}  # thesis Table 5.2
A1, A2 = math.radians(6.4), math.radians(21.8)


def sig4(x: float) -> float:
    return float(f"{x:.4g}")


def setup2_f25():
    """The 21.8 deg, b = 100 mm prism with the 25 mm lens of Table 5.3."""
    return thesis_setup2().replace(focal_length_mm=25.0)


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


def test_exact_fov_type_switches_at_alpha1_and_alpha2():
    b = boundary_angles(N, 4.7616, F)
    base = thesis_setup1()  # sensor 4.7616 mm, f 25 mm
    expected = {b.alpha1: ("divergent", "semi-divergent"), b.alpha2: ("semi-divergent", "convergent")}
    for boundary, (below, above) in expected.items():
        for delta, want in ((-0.01, below), (0.01, above)):
            rig = base.replace(alpha_deg=math.degrees(boundary) + delta)
            assert exact_fov_type(rig) == want == fov_closed_form(rig).fov_type


def test_thesis_setups_types():
    # Table 5.3's set-ups: 1 semi-divergent (the thesis calls it divergent), 3 divergent, 2 and 4 convergent
    assert fov_type(A1, N, 4.7616, F) == "semi-divergent"
    assert fov_type(A1, N, 6.3984, F) == "divergent"
    assert fov_type(A2, N, 4.7616, F) == fov_type(A2, N, 6.3984, F) == "convergent"


# ----------------------------------------------------------------------------- closed form vs exact model
@pytest.mark.parametrize(
    "make",
    [thesis_setup1, setup2_f25,
     lambda: thesis_setup1().replace(prism_offset_x_mm=5.0),
     lambda: thesis_setup1().replace(prism_offset_x_mm=-8.0, apex_distance_mm=210.0),
     lambda: thesis_setup1().replace(principal_point=(400.0, 383.5))],
    ids=["setup1", "setup2_f25", "offset+5", "offset-8", "off-centre-pp"],
)
def test_closed_form_rays_match_exact_fov(make):
    rig = make()
    fov = fov_closed_form(rig)
    assert fov.edge_rays_on_prism
    z_b = rig.apex_distance_mm + rig.prism_thickness_mm
    depths = torch.tensor([z_b + 1.0, 400.0, 900.0, 2500.0], dtype=F64)
    cmp = compare_fov(rig, depths)
    assert cmp.worst < 1e-8
    assert torch.equal(cmp.closed_form.overlap, cmp.exact.overlap)


def test_edge_rays_missing_the_prism_are_flagged():
    # The library's setup 2 (f 8 mm): the sensor-edge rays reach x = 57.5 mm on the face of the 100 mm
    # prism, so Ray 2 of eq. 5.25 is not the border; the prism's edge is. The common FOV still matches while
    # Ray 1 bounds it (before the closed-form crossing at 675 mm), and is overestimated after it.
    rig = thesis_setup2()
    fov = fov_closed_form(rig)
    assert not fov.edge_rays_on_prism and float(fov.crossing_depth) == pytest.approx(674.6, abs=0.1)
    cmp = compare_fov(rig, [200.0, 400.0, 2500.0])
    assert torch.allclose(cmp.closed_form.width[:2], cmp.exact.width[:2], atol=1e-8)
    assert float(cmp.closed_form.width[2] / cmp.exact.width[2]) > 1.4  # 473 mm vs 329 mm


def test_ray1_lines_are_the_traced_apex_rays_with_offset():
    # eq. 5.27-5.33 with the intercepts paired as eq. 5.30-5.33 say (eq. 5.36-5.37 swap them)
    rig = thesis_setup1().replace(prism_offset_x_mm=8.0)
    fov = fov_closed_form(rig)
    for half in ("left", "right"):
        ray = apex_ray(rig, half)
        line = getattr(fov, f"{half}_ray1")
        assert float(line.intercept) == pytest.approx(float(ray.origins[0]), abs=1e-12)
        assert float(line.angle) == pytest.approx(math.atan2(float(ray.directions[0]), float(ray.directions[2])),
                                                  abs=1e-14)
    swapped = abs(float(fov.left_ray1.intercept - fov.right_ray1.intercept))
    assert swapped > 0.4  # the error of eq. 5.36-5.37's pairing, in mm


def test_offset_shifts_rays2_by_delta_v_and_changes_gamma_slightly():
    base, moved = thesis_setup1(), thesis_setup1().replace(prism_offset_x_mm=8.0)
    f0, f8 = fov_closed_form(base), fov_closed_form(moved)
    _, dv = offset_shift(base.alpha_rad, N, 4.7616, F, 8.0)
    assert float(dv) == pytest.approx(0.0615, abs=1e-4)
    for half in ("left", "right"):  # eq. 5.35: both Rays 2 move by -Delta v, angles unchanged
        r0, r8 = getattr(f0, f"{half}_ray2"), getattr(f8, f"{half}_ray2")
        assert float(r8.intercept - r0.intercept) == pytest.approx(-float(dv), abs=1e-12)
        assert float(r8.angle) == pytest.approx(float(r0.angle), abs=1e-15)
    # gamma is not exactly constant (sec. 5.4.2 says it is): +0.19 % at d = 8 mm
    assert float(f8.gamma / f0.gamma - 1) == pytest.approx(0.00186, abs=2e-5)


def test_apex_distance_moves_ray2_only_and_matters_past_the_crossing():
    near, far = thesis_setup1(), thesis_setup1().replace(apex_distance_mm=210.0)
    fn, ff = fov_closed_form(near), fov_closed_form(far)
    assert float(fn.h) == float(ff.h) and float(ff.v) > float(fn.v)  # sec. 5.4.1
    assert float(fn.crossing_depth) == pytest.approx(1402.5, abs=0.1)
    # Before the crossing the common FOV is bounded by Ray 1 (same absolute x for both T_o: it is fixed to
    # the back plane, which moves by 40 mm, so compare at the same distance past the back plane).
    wn = fov_extent(fn, [1000.0]).width
    wf = fov_extent(ff, [1040.0]).width
    assert float(wn) == pytest.approx(float(wf), abs=1e-9)
    # past it Ray 2 bounds it and T_o matters (sec. 6.3.3 says it does not): 262.0 vs 269.7 mm
    w3n = float(fov_extent(fn, [3000.0]).width)
    w3f = float(fov_extent(ff, [3040.0]).width)
    assert w3n == pytest.approx(262.01, abs=0.01) and w3f == pytest.approx(269.69, abs=0.01)


def test_alpha_sweep_worst_difference():
    depths = [300.0, 1000.0, 3000.0]
    sweep = fov_alpha_sweep(thesis_setup1(), [1.0, 4.0, 6.4, 9.0, 12.0, 16.0, 20.0], depths)
    assert float(sweep.worst.max()) < 1e-8
    assert sweep.fov_types == ["divergent"] * 2 + ["semi-divergent"] * 2 + ["convergent"] * 3
    # keeping T = 5.6 mm the prism narrows with alpha; at 20 deg the edge rays miss it and Ray 2 is wrong
    narrow = fov_alpha_sweep(thesis_setup1(), [6.4, 20.0], depths, keep="thickness")
    assert float(narrow.worst[0]) < 1e-8 and float(narrow.worst[1]) > 1.0
    assert not fov_closed_form(thesis_setup1().replace(alpha_deg=20.0)).edge_rays_on_prism


def test_convergent_fov_closes_where_closed_form_says():
    rig = setup2_f25()
    fov = fov_closed_form(rig)
    far = float(fov.far_depth)
    assert fov.fov_type == "convergent" and math.isfinite(far)
    ext = exact_fov_extent(rig, [far - 5.0, far + 5.0])
    assert bool(ext.overlap[0]) and not bool(ext.overlap[1])


def test_exact_extent_other_row_and_dtype():
    rig = thesis_setup1()
    centre = exact_fov_extent(rig, [800.0])
    top = exact_fov_extent(rig, [800.0], row=0.0, samples=257)
    assert centre.width.dtype == F64 and torch.isfinite(top.width).all()
    assert abs(float(top.width - centre.width)) < 5.0  # rows see nearly the same band
    out = ray1_angle(torch.tensor([A1], dtype=torch.float32), torch.tensor(N))
    assert out.dtype == torch.float32
    alpha = torch.tensor(A1, dtype=F64, requires_grad=True)
    (g,) = torch.autograd.grad(ray1_angle(alpha, N), alpha)
    assert 0.45 < float(g) < 0.5  # ~ n - 1 for a thin prism


# ----------------------------------------------------------------------------- invalid input
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
    with pytest.raises(AnalysisError, match="untilted"):
        fov_closed_form(thesis_setup1().replace(prism_tilt_deg=(0.0, 1.0, 0.0)))
    with pytest.raises(AnalysisError, match="beyond the prism's back plane"):
        exact_fov_extent(thesis_setup1(), [100.0])
    with pytest.raises(AnalysisError, match="beyond the prism's back plane"):
        fov_extent(fov_closed_form(thesis_setup1()), [170.0])
    with pytest.raises(AnalysisError, match="off the sensor"):
        exact_fov_extent(thesis_setup1(), [500.0], row=-3.0)
    with pytest.raises(AnalysisError, match="samples"):
        exact_fov_extent(thesis_setup1(), [500.0], samples=2)
    with pytest.raises(AnalysisError, match="rig must be a BiPrismRig"):
        fov_closed_form(thesis_setup1().parameters())
    with pytest.raises(OptionError, match="Unknown keep"):
        fov_alpha_sweep(thesis_setup1(), [6.4], [500.0], keep="depth")
