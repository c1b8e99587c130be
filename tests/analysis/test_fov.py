"""A rig's closed-form FOV (thesis ch. 5) against the exact ray-traced FOV."""

import math

import pytest
import torch

from prismstereo import OptionError, thesis_setup1, thesis_setup2
from prismstereo.analysis import (
    AnalysisError,
    boundary_angles,
    compare_fov,
    exact_fov_extent,
    exact_fov_type,
    fov_alpha_sweep,
    fov_closed_form,
    fov_extent,
    offset_shift,
)
from prismstereo.geometry import apex_ray

F64 = torch.float64
N, F = 1.48, 25.0
SENSORS = {"CV-M9CL": 4.7616, "CB-140MCL": 6.3984}  # thesis Table 5.2


def setup2_f25():
    """The 21.8 deg, b = 100 mm prism with the 25 mm lens of Table 5.3."""
    return thesis_setup2().replace(focal_length_mm=25.0)


# ----------------------------------------------------------------------------- FOV type (Table 5.1)
def test_exact_fov_type_switches_at_alpha1_and_alpha2():
    b = boundary_angles(N, 4.7616, F)
    base = thesis_setup1()  # sensor 4.7616 mm, f 25 mm
    expected = {b.alpha1: ("divergent", "semi-divergent"), b.alpha2: ("semi-divergent", "convergent")}
    for boundary, (below, above) in expected.items():
        for delta, want in ((-0.01, below), (0.01, above)):
            rig = base.replace(alpha_deg=math.degrees(boundary) + delta)
            assert exact_fov_type(rig) == want == fov_closed_form(rig).fov_type


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


# ----------------------------------------------------------------------------- invalid input
def test_invalid_parameters_raise():
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
