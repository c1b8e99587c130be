import pytest
import torch

from prismstereo import OptionError, RigError, ShapeError, thesis_setup1, thesis_setup2
from prismstereo.epipolar import depth_hypotheses, exact_sampling_grid
from prismstereo.epipolar.sweep import (
    chebyshev_basis,
    depth_to_sweep,
    evaluate_sweep,
    fit_sweep,
    inverse_to_sweep,
    sweep_coefficients,
    sweep_match,
    sweep_positions,
    sweep_to_depth,
    sweep_to_inverse,
)
from prismstereo.geometry.projection import solve_projection
from tests.conftest import RIGS, scaled_rig


def test_chebyshev_basis_matches_torch_special():
    x = torch.linspace(-1, 1, 11, dtype=torch.float64)
    ours = chebyshev_basis(x, 6)
    ref = torch.stack([torch.special.chebyshev_polynomial_t(x, k) for k in range(6)], -1)
    torch.testing.assert_close(ours, ref)
    assert chebyshev_basis(x, 1).shape == (11, 1)
    with pytest.raises(OptionError, match="n must be >= 1"):
        chebyshev_basis(x, 0)


def test_sweep_coordinate_round_trip_and_ends():
    z = torch.tensor([228.0, 400.0, 1374.0], dtype=torch.float64)
    rng = torch.tensor([228.0, 1374.0], dtype=torch.float64)
    s = depth_to_sweep(z, rng)
    assert s[0] == -1 and s[-1] == 1
    torch.testing.assert_close(sweep_to_depth(s, rng), z)
    # uniform s is uniform inverse depth, the spacing of depth_hypotheses
    torch.testing.assert_close(sweep_to_depth(torch.linspace(-1, 1, 7, dtype=torch.float64), rng),
                               depth_hypotheses(228.0, 1374.0, 7))
    # through the inverse depth: the same bits, and affine (a mean of inverse depths is the mean of s)
    assert torch.equal(depth_to_sweep(z, rng), inverse_to_sweep(1.0 / z, rng))
    assert torch.equal(sweep_to_depth(s, rng), 1.0 / sweep_to_inverse(s, rng))
    torch.testing.assert_close(inverse_to_sweep((1.0 / z).mean(), rng), s.mean())
    torch.testing.assert_close(sweep_to_inverse(s, rng), 1.0 / z)


@pytest.mark.parametrize("name", sorted(RIGS))
def test_fit_reproduces_the_exact_grid(name):
    rig = RIGS[name]()
    fit = fit_sweep(rig, (228.0, 1374.0))
    depths = depth_hypotheses(228.0, 1374.0, 5)
    rows = torch.arange(3.0, rig.image_height, 151.0, dtype=torch.float64)
    exact = exact_sampling_grid(rig, depths, rows)
    uv = torch.stack(torch.meshgrid(torch.arange(rig.reference_width, dtype=torch.float64), rows,
                                    indexing="xy"), -1)
    est = sweep_positions(fit, uv, depth_to_sweep(depths, fit.z_range).view(-1, 1, 1))
    err = (est - exact.uv).norm(dim=-1)[exact.valid]
    assert err.numel() > 1000 and err.max() < (1e-4 if name == "setup2" else 1e-8)
    assert fit.max_error_px < 1e-3


def test_fit_continues_beyond_the_field_of_view():
    """Pixels whose real match leaves the right half still get a smooth curve (the faces' planes)."""
    rig = scaled_rig(thesis_setup1(), 8)
    fit = fit_sweep(rig, (228.0, 1374.0))
    uv = torch.tensor([[0.0, 40.0]], dtype=torch.float64)  # far left: no real match at 228 mm
    pos = sweep_positions(fit, uv, torch.linspace(-1, 1, 50, dtype=torch.float64).view(-1, 1))
    assert torch.isfinite(pos).all() and (pos[1:] - pos[:-1]).norm(dim=-1).max() < 5.0


def test_coefficients_and_evaluation_shapes_float32():
    rig = scaled_rig(thesis_setup1(), 8)
    fit = fit_sweep(rig, (300.0, 1200.0))
    uv = torch.rand(4, 5, 2, generator=torch.Generator().manual_seed(0)) * 60
    c = sweep_coefficients(fit, uv)
    assert c.shape == (4, 5, fit.coefficients.shape[0], 2) and c.dtype == torch.float32
    s = torch.zeros(4, 5)
    assert evaluate_sweep(c, s).shape == (4, 5, 2)


def test_a_rigs_fit_is_kept_and_copied_bitwise():
    """A BiPrismRig's fit is computed once per rig and range: again it is a copy, bit for bit the fit of the rig's
    tensors (never kept), and changing one copy changes no later fit."""
    rig = scaled_rig(thesis_setup1(), 8).replace(prism_tilt_deg=(0.1, 0.0, 0.2))
    first = fit_sweep(rig, (310.0, 1190.0))
    again = fit_sweep(rig, [310, 1190.0])
    fresh = fit_sweep(rig.parameters(torch.zeros((), dtype=torch.float64)), (310.0, 1190.0))
    for fit in (again, fresh):
        assert torch.equal(fit.coefficients.view(torch.int64), first.coefficients.view(torch.int64))
        assert fit.max_error_px == first.max_error_px and torch.equal(fit.z_range, first.z_range)
    assert again.coefficients.data_ptr() != first.coefficients.data_ptr()
    first.coefficients.zero_()
    assert torch.equal(fit_sweep(rig, (310.0, 1190.0)).coefficients, again.coefficients)


def test_coefficients_of_many_pixels_are_blocked_bit_for_bit():
    """Without autograd, many pixels are evaluated in blocks (memory-bound otherwise): the same floats as the one
    einsum that autograd keeps."""
    rig = scaled_rig(thesis_setup1(), 8)
    fit = fit_sweep(rig, (300.0, 1200.0))
    uv = torch.stack(torch.meshgrid(torch.arange(64.0), torch.arange(96.0), indexing="xy"), -1).double()
    uv = torch.cat([uv, uv + 0.37])  # 12288 pixels: 3 blocks
    blocked = sweep_coefficients(fit, uv)
    whole = sweep_coefficients(fit, uv.clone().requires_grad_(True))
    assert blocked.shape == whole.shape == (192, 64, fit.coefficients.shape[0], 2) and whole.requires_grad
    assert torch.equal(blocked.view(torch.int64), whole.detach().view(torch.int64))


def test_fit_is_differentiable_wrt_rig_parameters():
    rig = scaled_rig(thesis_setup1(), 16)
    p = rig.parameters(torch.zeros((), dtype=torch.float64))
    alpha = p.alpha.clone().requires_grad_(True)
    fit = fit_sweep(p._replace(alpha=alpha), (300.0, 1200.0), tolerance_px=1e-6)
    uv = torch.tensor([[10.0, 20.0]], dtype=torch.float64)
    pos = sweep_positions(fit, uv, torch.tensor([0.3], dtype=torch.float64))
    pos[0, 0].backward()
    # finite difference of the exact projection
    from prismstereo.geometry.optics import points_at_depth, trace_pixels

    def exact(a: float) -> float:
        q = p._replace(alpha=torch.tensor(a, dtype=torch.float64))
        z = sweep_to_depth(torch.tensor(0.3, dtype=torch.float64), fit.z_range.detach())
        pt = points_at_depth(trace_pixels(q, uv, half="left"), z)
        return float(solve_projection(q, pt, "right").uv[0, 0])

    h = 1e-6
    fd = (exact(float(p.alpha) + h) - exact(float(p.alpha) - h)) / (2 * h)
    assert abs(float(alpha.grad) - fd) < 1e-4 * abs(fd)


def test_fit_errors():
    rig = scaled_rig(thesis_setup2(), 8)
    with pytest.raises(RigError, match="beyond the prism's back plane"):
        fit_sweep(rig, (50.0, 1000.0))
    with pytest.raises(RigError, match="increasing"):
        fit_sweep(rig, (900.0, 500.0))
    with pytest.raises(OptionError, match="at least 2 nodes"):
        fit_sweep(rig, (300.0, 900.0), nodes_uv=1)
    with pytest.raises(RigError, match="sweep fit error"):
        fit_sweep(rig, (228.0, 1374.0), nodes_uv=2, nodes_depth=2, tolerance_px=1e-12, max_nodes=4)


def test_sweep_match_is_the_sweep_and_its_slope():
    half = thesis_setup1().binned(2)
    uv = torch.rand(4, 6, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(1)) * torch.tensor(
        [250.0, 380.0], dtype=torch.float64)
    c = sweep_coefficients(fit_sweep(half, (228.0, 1374.0)), uv)  # (4, 6, N, 2)
    s = torch.rand(1, 1, 4, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(2)) * 2 - 1
    match, slope = sweep_match(c.permute(2, 3, 0, 1), s)
    assert torch.allclose(match[0].permute(1, 2, 0), evaluate_sweep(c, s[0, 0]), atol=1e-9)
    h = 1e-6
    numeric = (evaluate_sweep(c, s[0, 0] + h) - evaluate_sweep(c, s[0, 0] - h)) / (2 * h)
    assert torch.allclose(slope[0].permute(1, 2, 0), numeric, atol=1e-5)
    small = c[:2, :2].permute(2, 3, 0, 1).contiguous()
    probe = s[..., :2, :2].clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: sweep_match(small, x)[0], (probe,))
    with pytest.raises(ShapeError, match="coefficients"):
        sweep_match(torch.zeros(3, 4, 5), s)
