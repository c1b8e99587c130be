"""Depth equations and sensitivities of thesis ch. 6 against autograd and the exact ray-traced model."""

import math

import pytest
import torch

from prismstereo import OptionError, RigError, thesis_setup1, thesis_setup2
from prismstereo.analysis import (
    AnalysisError,
    Sensitivities,
    Uncertainties,
    closed_form_sensitivities,
    depth_exact,
    depth_planar,
    depth_small_angle,
    disparity_mm,
    disparity_small_angle,
    error_budget,
    error_curves,
    exact_dz_dd,
    exact_sensitivities,
    project_pair,
    small_angle_check,
)

F64 = torch.float64


def with_alpha(alpha_deg: float):
    """Setup 1 with another prism angle, keeping the 100 mm back plane."""
    rig = thesis_setup1()
    thickness = rig.prism_width_mm / 2 * math.tan(math.radians(alpha_deg))
    return rig.replace(alpha_deg=alpha_deg, prism_thickness_mm=thickness)


# ----------------------------------------------------------------------------- disparity and depth models
def test_disparity_definition_and_asymptote():
    rig = thesis_setup1()
    z = torch.tensor([250.0, 500.0, 1000.0, 5000.0, 1e6], dtype=F64)
    pair = project_pair(rig, torch.stack([torch.zeros_like(z), torch.zeros_like(z), z], -1))
    assert pair.valid.all()
    d = pair.disparity
    assert torch.equal(d, (pair.uv_right[:, 0] - pair.uv_left[:, 0]) * rig.pixel_size_mm)
    assert torch.equal(d, disparity_mm(rig, pair.uv_left, pair.uv_right))
    assert (d > 0).all() and (d.diff() > 0).all()  # grows with depth
    # eq. 6.15's asymptote 2 f alpha (n - 1) is 0.85 % below the exact limit
    d_inf_615 = 2 * rig.focal_length_mm * rig.alpha_rad * (rig.refractive_index - 1)
    assert float(d[-1] / d_inf_615 - 1) == pytest.approx(0.0085, abs=2e-4)


def test_small_angle_depth_roundtrip_and_dtype():
    rig = thesis_setup1()
    z = torch.tensor([200.0, 800.0, 3000.0], dtype=F64)
    assert torch.allclose(depth_small_angle(rig, disparity_small_angle(rig, z)), z, rtol=1e-12)
    out = depth_small_angle(rig, torch.tensor([1.5], dtype=torch.float32))
    assert out.dtype == torch.float32


@pytest.mark.parametrize(
    "make", [thesis_setup1, thesis_setup2, lambda: thesis_setup1().replace(prism_offset_x_mm=4.0)],
    ids=["setup1", "setup2", "offset"],
)
def test_planar_general_form_is_exact_on_the_principal_row(make):
    rig = make()
    gen = torch.Generator().manual_seed(3)
    z = 300.0 + 1500.0 * torch.rand(50, generator=gen, dtype=F64)
    x = (torch.rand(50, generator=gen, dtype=F64) - 0.5) * 0.04 * z + rig.prism_offset_x_mm
    pts = torch.stack([x, torch.zeros_like(z), z], -1)
    pair = project_pair(rig, pts)
    assert pair.valid.sum() > 40
    xl = (pair.uv_left[:, 0] - rig.cx) * rig.pixel_size_mm
    xr = (pair.uv_right[:, 0] - rig.cx) * rig.pixel_size_mm
    zz = depth_planar(rig, xl, xr)
    assert ((zz - z) / z)[pair.valid].abs().max() < 1e-9


def test_exact_depth_roundtrip_random_3d_points():
    rig = thesis_setup1().replace(prism_offset_x_mm=-1.0, prism_tilt_deg=(0.5, -1.0, 0.3))
    gen = torch.Generator().manual_seed(0)
    z = 300.0 + 2000.0 * torch.rand(200, generator=gen, dtype=F64)
    xy = (torch.rand(200, 2, generator=gen, dtype=F64) - 0.5) * 0.05 * z[:, None]
    pts = torch.cat([xy, z[:, None]], -1)
    pair = project_pair(rig, pts)
    out = depth_exact(rig, pair.uv_left, pair.uv_right)
    ok = pair.valid & out.valid
    assert ok.sum() > 150
    assert (out.points - pts)[ok].abs().max() < 1e-6


def test_where_eq_6_15_exceeds_one_percent():
    rig = thesis_setup1()
    chk = small_angle_check(rig, [500.0, 550.0, 575.0, 1000.0, 2000.0], lateral_fractions=(0.0,))
    err = chk.error_small_angle[:, 0]
    assert err[1] < 0.01 < err[2]  # on the axis it crosses 1 % between 550 and 575 mm (562 mm)
    assert chk.first_depth_over == 575.0
    assert float(err[3]) == pytest.approx(0.0304, abs=5e-4) and float(err[4]) == pytest.approx(0.0855, abs=5e-4)
    assert chk.error_planar.abs().max() < 1e-10  # the general form stays exact
    wide = small_angle_check(rig, [500.0])  # near the FOV's borders it fails sooner
    assert wide.error_small_angle.abs().max() > 0.01 and wide.first_depth_over == 500.0
    off_row = small_angle_check(rig, [1000.0], lateral_fractions=(0.0,), y_mm=100.0)
    assert off_row.error_planar.abs().max() > 0.01  # the top-view forms ignore y


# ----------------------------------------------------------------------------- sensitivities
def test_closed_forms_are_derivatives_of_eq_6_15():
    rig = thesis_setup1()
    z = torch.tensor([300.0, 1000.0, 2500.0], dtype=F64)
    p = rig.parameters(dtype=F64, requires_grad=True)
    d = disparity_small_angle(rig, z).detach().requires_grad_(True)
    zz = depth_small_angle(p, d)
    assert torch.allclose(zz, z, rtol=1e-12)
    cf = closed_form_sensitivities(rig, z)
    thesis = closed_form_sensitivities(rig, z, n_form="thesis")
    for i in range(3):
        grads = torch.autograd.grad(zz[i], [d, p.T_o, p.alpha, p.f, p.n, p.T], retain_graph=True)
        auto = Sensitivities(grads[0][i], *grads[1:])
        for name in Sensitivities._fields:
            assert float(getattr(cf, name)[i]) == pytest.approx(float(getattr(auto, name)), rel=1e-9), name
    # eq. 6.33/6.34 as printed: off by (2 T_o + T) / n^2
    n, t_o, t = rig.refractive_index, rig.apex_distance_mm, rig.prism_thickness_mm
    assert torch.allclose(cf.n - thesis.n, torch.full_like(z, (2 * t_o + t) / n**2), rtol=1e-12)
    assert (2 * t_o + t) / n**2 == pytest.approx(157.78, abs=0.01)


def test_closed_form_and_exact_sensitivities_agree_in_the_small_angle_regime():
    z = torch.tensor([300.0, 1000.0, 2000.0], dtype=F64)
    worst = {}
    for alpha in (1.0, 2.0, 6.4):
        rig = with_alpha(alpha)
        cf, ex = closed_form_sensitivities(rig, z), exact_sensitivities(rig, z)
        worst[alpha] = max(float(((getattr(cf, k) - getattr(ex, k)) / getattr(ex, k)).abs().max())
                           for k in Sensitivities._fields)
    assert worst[1.0] < 1e-3 and worst[2.0] < 3e-3  # agree where alpha is small ...
    assert worst[2.0] / worst[1.0] == pytest.approx(4.0, rel=0.05)  # ... with an O(alpha^2) gap
    assert 0.015 < worst[6.4] < 0.03  # setup 1: dZ/dD differs by 2.1 %


def test_exact_sensitivities_match_finite_differences():
    rig = thesis_setup1()
    z = 800.0
    ex = exact_sensitivities(rig, [z])
    pair = project_pair(rig, torch.tensor([[0.0, 0.0, z]], dtype=F64))
    for field, name, h in (("apex_distance_mm", "T_o", 1e-3), ("focal_length_mm", "f", 1e-4),
                           ("refractive_index", "n", 1e-6)):
        value = getattr(rig, field)
        up = depth_exact(rig.replace(**{field: value + h}), pair.uv_left, pair.uv_right).depth
        down = depth_exact(rig.replace(**{field: value - h}), pair.uv_left, pair.uv_right).depth
        assert float(getattr(ex, name)[0]) == pytest.approx(float((up - down) / (2 * h)), rel=1e-5), name
    moved = pair.uv_right + torch.tensor([[0.01, 0.0]], dtype=F64)
    fd = (depth_exact(rig, pair.uv_left, moved).depth - z) / (0.01 * rig.pixel_size_mm)
    assert float(ex.D[0]) == pytest.approx(float(fd), rel=1e-4)
    assert float(exact_dz_dd(rig, [z])[0]) == pytest.approx(float(ex.D[0]), rel=1e-12)


def test_error_budget_defaults_and_models():
    rig = thesis_setup1().replace(apex_distance_mm=210.0)  # Table 6.1
    z = torch.tensor([500.0, 1000.0, 2000.0], dtype=F64)
    budget = error_budget(rig, z)
    u = Uncertainties()
    assert (u.disparity_px, u.focal_length_mm, u.alpha_rad, u.apex_distance_mm, u.refractive_index) == (
        1.0, 0.1, 0.001, 1.0, 0.01)
    assert torch.allclose(budget.contributions.D, budget.sensitivities.D.abs() * rig.pixel_size_mm)
    assert torch.allclose(budget.contributions.n, budget.sensitivities.n.abs() * 0.01)
    assert torch.allclose(budget.total, torch.stack(list(budget.contributions)).sum(0))
    assert torch.allclose(budget.relative, budget.total / z)
    # relative error of dT_o is range independent (thesis deduction 1), of dn it grows with Z (not deduction 4)
    rel_to, rel_n = budget.contributions.T_o / z, budget.contributions.n / z
    assert float(rel_to.max() - rel_to.min()) < 2e-5
    assert [round(v, 3) for v in rel_n.tolist()] == [0.028, 0.078, 0.177]
    exact = error_budget(rig, z, model="exact")
    assert torch.allclose(exact.total, budget.total, rtol=0.01)
    none = error_budget(rig, z, Uncertainties(focal_length_mm=0, alpha_rad=0, apex_distance_mm=0, refractive_index=0))
    assert torch.allclose(none.total, error_curves(rig, z).closed_form)


def test_error_curves_quadratic_in_depth():
    curves = error_curves(thesis_setup1(), [500.0, 1000.0, 2000.0], disparity_px=2.0)
    ratio = curves.exact[1:] / curves.exact[:-1]
    assert ((ratio > 3.8) & (ratio < 4.2)).all()
    assert float(curves.closed_form[1] / curves.exact[1] - 1) == pytest.approx(0.0178, abs=1e-3)


def test_invalid_input_raises():
    rig = thesis_setup1()
    with pytest.raises(AnalysisError, match="depths must be finite and positive"):
        closed_form_sensitivities(rig, [-5.0])
    with pytest.raises(OptionError, match="Unknown n_form"):
        closed_form_sensitivities(rig, [500.0], n_form="printed")
    with pytest.raises(OptionError, match="Unknown model"):
        error_budget(rig, [500.0], model="pinhole")
    with pytest.raises(AnalysisError, match="not seen by both halves"):
        exact_sensitivities(rig, [1000.0], lateral_mm=300.0)
    with pytest.raises(AnalysisError, match="uncertainty alpha_rad must be"):
        Uncertainties(alpha_rad=-1.0)
    with pytest.raises(AnalysisError, match="must be an Uncertainties"):
        error_budget(rig, [500.0], uncertainties={"alpha_rad": 0.1})
    with pytest.raises(AnalysisError, match="disparity_px must be > 0"):
        error_curves(rig, [500.0], disparity_px=0.0)
    with pytest.raises(AnalysisError, match="threshold"):
        small_angle_check(rig, [500.0], threshold=2.0)
    with pytest.raises(RigError, match="rig must be a BiPrismRig or RigParameters"):
        depth_small_angle("thesis_setup1", 1.0)
