"""Variable-parameter design (thesis sec. 6.3): closed forms, their round trips, the exact solver."""

import math

import pytest
import torch

from prismstereo import OptionError, thesis_setup1, thesis_setup2
from prismstereo.analysis import (
    VARY,
    AnalysisError,
    closed_form_error,
    closed_form_sensitivities,
    design,
    error_curves_of,
    exact_dz_dd,
    required_apex_distance,
    required_focal_length,
    required_pixels,
    required_thickness,
)

Z, TARGET = 1000.0, 10.0


def test_eq_6_36_is_the_disparity_term_of_eq_6_22():
    rig = thesis_setup1()
    for z in (400.0, 1000.0, 2500.0):
        dzdd = float(closed_form_sensitivities(rig, [z]).D[0])
        assert closed_form_error(rig, z, 2.0) == pytest.approx(dzdd * 2 * rig.pixel_size_mm, rel=1e-12)
    assert closed_form_error(rig, Z) == pytest.approx(10.1661, abs=1e-4)


def test_focal_length_and_apex_distance_round_trip():
    rig = thesis_setup1()
    f = required_focal_length(rig, Z, TARGET)
    t_o = required_apex_distance(rig, Z, TARGET)
    assert closed_form_error(rig.replace(focal_length_mm=f), Z) == pytest.approx(TARGET, rel=1e-12)
    assert closed_form_error(rig.replace(apex_distance_mm=t_o), Z) == pytest.approx(TARGET, rel=1e-12)
    assert (round(f, 4), round(t_o, 3)) == (25.4154, 172.825)


def test_pixel_count_eq_6_41():
    rig = thesis_setup1()
    own = required_pixels(rig, Z, closed_form_error(rig, Z))
    assert own.width_px == pytest.approx(rig.image_width, rel=1e-12)
    assert own.height_px == pytest.approx(rig.image_height, rel=1e-12)
    assert own.pixels == pytest.approx(rig.image_width * rig.image_height / 2, rel=1e-12)
    half = required_pixels(rig, Z, closed_form_error(rig, Z) / 2)  # half the error: 4x the pixels (eq. 6.41)
    assert half.pixels / own.pixels == pytest.approx(4.0, rel=1e-12)
    assert required_pixels(rig, 2 * Z, closed_form_error(rig, Z)).pixels / own.pixels == pytest.approx(
        ((2 * Z - rig.prism_thickness_mm * 0.48 / 1.48) / (Z - rig.prism_thickness_mm * 0.48 / 1.48)) ** 4)


def test_thickness_roots_eq_6_44_to_6_46():
    rig = thesis_setup1()
    d = required_thickness(rig, Z, TARGET)
    n = rig.refractive_index
    c = n * Z / (n - 1)
    assert d.thickness * d.rejected == pytest.approx(c * c, rel=1e-12)  # Vieta
    assert d.rejected > c > Z  # T+ would put the prism past the object: rejected
    designed = rig.replace(prism_thickness_mm=d.thickness, alpha_deg=math.degrees(d.thickness / d.half_width))
    assert closed_form_error(designed, Z) == pytest.approx(TARGET, rel=1e-10)  # with alpha = T / t_b (6.42)
    # with the rig's own error as target, T- returns the rig's T up to alpha vs tan(alpha) (fig. 6.11)
    own = required_thickness(rig, Z, closed_form_error(rig, Z))
    assert own.thickness == pytest.approx(rig.prism_thickness_mm * rig.alpha_rad / math.tan(rig.alpha_rad), rel=1e-4)
    assert own.thickness == pytest.approx(5.6, rel=0.005) and own.thickness != pytest.approx(5.6, rel=1e-3)


@pytest.mark.parametrize("vary", VARY)
def test_exact_design_meets_target_and_differs_from_closed_form(vary):
    rig = thesis_setup1()
    d = design(rig, target_error_mm=TARGET, depth_mm=Z, vary=vary)
    assert d.exact_rig is not None and d.closed_form_rig is not None
    exact_error = float(exact_dz_dd(d.exact_rig, [Z])[0]) * rig.pixel_size_mm
    assert exact_error == pytest.approx(TARGET, rel=1e-8)
    assert d.difference == d.closed_form - d.exact
    # the thesis' design misses the target on the exact model by ~1.4-1.8 % (the dZ/dD gap)
    assert 0.01 < abs(d.difference / d.exact) < 0.025
    assert 9.7 < d.closed_form_error_exact < 9.95
    assert d.current_error[0] == pytest.approx(10.1661, abs=1e-4) and d.current_error[1] == pytest.approx(9.9884,
                                                                                                         abs=1e-4)
    assert (d.pixels is not None) == (vary == "f")


def test_design_unreachable_and_invalid():
    rig = thesis_setup1()
    # 10 mm at 2 m needs alpha ~ 26 deg: a convergent FOV that closes before 2 m
    with pytest.raises(AnalysisError, match="no alpha reaches"):
        design(rig, target_error_mm=10.0, depth_mm=2000.0, vary="alpha")
    with pytest.raises(OptionError, match="Unknown vary"):
        design(rig, target_error_mm=10.0, depth_mm=Z, vary="n")
    with pytest.raises(AnalysisError, match="target_error_mm must be a positive number"):
        design(rig, target_error_mm=-1.0, depth_mm=Z, vary="f")
    with pytest.raises(AnalysisError, match="beyond the prism's back plane"):
        required_thickness(rig, 150.0, 1.0)
    with pytest.raises(AnalysisError, match="half_width_mm must be > 0"):
        required_thickness(rig, Z, 1.0, half_width_mm=0.0)
    with pytest.raises(AnalysisError, match="theta_vc"):
        required_pixels(rig, Z, 1.0, theta_vc=2.0)
    with pytest.raises(AnalysisError, match="rig must be a BiPrismRig"):
        closed_form_error(rig.parameters(), Z)


def test_error_curves_of_marks_unseen_depths():
    conv = thesis_setup2().replace(focal_length_mm=25.0)  # convergent: its common FOV closes at 353 mm
    curves = error_curves_of({"setup 1": thesis_setup1(), "convergent": conv}, [250.0, 600.0])
    assert torch.isfinite(curves["setup 1"].exact).all()
    assert math.isfinite(float(curves["convergent"].exact[0])) and math.isnan(float(curves["convergent"].exact[1]))
    assert torch.isfinite(curves["convergent"].closed_form).all()
