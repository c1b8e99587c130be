import pytest
import torch

from prismstereo import OptionError, ShapeError, thesis_setup1, thesis_setup2
from prismstereo.epipolar.sweep import chebyshev_basis, fit_sweep, sweep_coefficients
from prismstereo.epipolar.table import (
    band_positions,
    column_to_sweep,
    cubic_at,
    local_cubic,
    tabulate_sweep,
    valid_interval,
)
from prismstereo.matching.sweep_cost import warp_slices
from prismstereo.model import PrismStereo

F64 = torch.float64


def _coefficients(rig, z_range=(228.0, 1374.0)):
    uv = torch.stack(torch.meshgrid(torch.arange(rig.reference_width, dtype=F64),
                                    torch.arange(rig.image_height, dtype=F64), indexing="xy"), -1)
    return sweep_coefficients(fit_sweep(rig, z_range), uv).permute(2, 0, 1, 3).contiguous()


def _exact(coef, s):  # (N, H, W, 2) at per-pixel s (B, J, H, W) -> (B, J, H, W, 2)
    basis = chebyshev_basis(s, coef.shape[0])
    return torch.einsum("bjhwn,nhwk->bjhwk", basis, coef)


@pytest.mark.parametrize("setup", [thesis_setup1, thesis_setup2])
def test_local_cubics_match_the_polynomials(setup):
    coef = _coefficients(setup().downscaled(2))
    table = tabulate_sweep(coef, tolerance_px=1e-3)
    assert table.shape[0] in (17, 33, 65) and table.shape[1:] == coef.shape[1:]
    gen = torch.Generator().manual_seed(5)
    s = torch.rand(2, 1, *coef.shape[1:3], generator=gen, dtype=F64) * 2 - 1
    cubic = local_cubic(table, s)
    assert (cubic_at(cubic, cubic.u) - _exact(coef, s)).norm(dim=-1).max() < 2e-3
    band_of_rows = local_cubic(table, s[..., 5:12, :], top=5)  # rows of the whole table, as the fine band's strips
    assert torch.equal(band_of_rows.coefficients, cubic.coefficients[..., 5:12, :, :])
    assert torch.equal(band_of_rows.u, cubic.u[..., 5:12, :])
    # the band by one matrix product = the cubic at shifted coordinates = the polynomial
    offsets = torch.linspace(-0.03, 0.03, 7, dtype=F64)
    band = band_positions(cubic, offsets)
    assert band.shape == (2, 7, *coef.shape[1:3], 2)
    torch.testing.assert_close(band, cubic_at(cubic, cubic.u + offsets.view(1, -1, 1, 1) * cubic.scale))
    inner = (s + offsets.view(1, -1, 1, 1)).clamp(-1, 1)
    ok = (s + offsets.view(1, -1, 1, 1)).abs() <= 1
    assert (band - _exact(coef, inner)).norm(dim=-1)[ok].max() < 2e-3


def test_smallest_table_for_the_tolerance():
    coef = _coefficients(thesis_setup1().downscaled(4))
    assert tabulate_sweep(coef, 1e-3).shape[0] == 17
    assert tabulate_sweep(coef, 1e-9).shape[0] == 65  # unreachable: the largest table


def test_local_cubic_gradient():
    coef = _coefficients(thesis_setup1().downscaled(16))
    table = tabulate_sweep(coef)[:, :3, :4]
    s = torch.full((1, 1, 3, 4), 0.1234, dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: cubic_at(local_cubic(table, x), local_cubic(table, x).u), (s,))


@pytest.mark.parametrize("setup", [thesis_setup1, thesis_setup2])
def test_column_to_sweep_inverts_the_sweep(setup):
    """The column of the exact correspondence at s gives s back (to the table's 1e-3 px, ~1e-5 in s);
    columns beyond the searched range give its ends; gradients are finite and pass gradcheck."""
    coef = _coefficients(setup().downscaled(4))
    table = tabulate_sweep(coef)
    gen = torch.Generator().manual_seed(11)
    s = torch.rand(2, 1, *coef.shape[1:3], generator=gen, dtype=F64) * 1.96 - 0.98
    column = _exact(coef, s)[..., 0]
    back = column_to_sweep(table, column)
    speed = (table[-1, ..., 0] - table[0, ..., 0]).abs() / 2  # px per unit s
    assert ((back - s).abs() * speed).max() < 2e-3  # in px along the row
    beyond = column_to_sweep(table, torch.stack([table[0, ..., 0], table[-1, ..., 0]]).unsqueeze(1)
                             + torch.stack([-5 * torch.sign(speed), 5 * torch.sign(speed)]).unsqueeze(1))
    span_sign = torch.sign(table[-1, ..., 0] - table[0, ..., 0])
    assert torch.equal(beyond[0, 0], torch.where(span_sign > 0, -1.0, 1.0).to(F64))
    small = table[:, :2, :3]
    x = column[:1, :, :2, :3].clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda c: column_to_sweep(small, c), (x,))
    with pytest.raises(ShapeError, match="column"):
        column_to_sweep(table, column[:, 0])


@pytest.mark.parametrize("setup", [thesis_setup1, thesis_setup2])
def test_valid_interval_agrees_with_the_sampled_mask(setup):
    rig = setup().downscaled(4)
    model = PrismStereo(rig, (228.0, 1374.0), coarse_factor=1)
    table = model.table.double()
    lo, hi = valid_interval(table, model.other_valid, model.split.split)
    gen = torch.Generator().manual_seed(2)
    s = torch.rand(1, 16, *table.shape[1:3], generator=gen, dtype=F64) * 2 - 1
    cubic = local_cubic(table, s.reshape(16, 1, *table.shape[1:3]))
    xy = cubic_at(cubic, cubic.u)[:, 0].unsqueeze(0)  # (1, 16, H, W, 2) full-sensor pixels
    h, w_o = rig.image_height, rig.image_width - model.split.split
    grid = torch.stack([(2 * (xy[..., 0] - model.split.split) + 1) / w_o - 1, (2 * xy[..., 1] + 1) / h - 1], -1)
    sampled = warp_slices(torch.zeros(1, 1, h, w_o, dtype=F64), grid, model.other_valid).valid
    by_interval = (s >= lo) & (s <= hi)
    assert (by_interval == sampled).double().mean() > 0.999
    assert not (by_interval & ~sampled).any()  # the interval never admits a sample the mask rejects
    assert sampled.double().mean() > 0.3


def test_errors():
    table = torch.zeros(17, 3, 4, 2)
    with pytest.raises(ShapeError, match="table"):
        local_cubic(torch.zeros(3, 3, 4, 2), torch.zeros(1, 1, 3, 4))
    with pytest.raises(ShapeError, match="s must have shape"):
        local_cubic(table, torch.zeros(1, 2, 3, 4))
    with pytest.raises(ShapeError, match="from row 2"):
        local_cubic(table, torch.zeros(1, 1, 2, 4), top=2)  # rows 2-3 of a 3-row table
    with pytest.raises(ShapeError, match="needs K >= 4"):
        local_cubic(table, torch.zeros(1, 1, 3, 5))
    with pytest.raises(OptionError, match="tolerance_px must be > 0"):
        tabulate_sweep(torch.zeros(5, 3, 4, 2), 0.0)
    with pytest.raises(OptionError, match="steps must be an int >= 0"):
        valid_interval(table, torch.ones(3, 4, dtype=torch.bool), 4, steps=-1)
    with pytest.raises(ShapeError, match="offsets"):
        band_positions(local_cubic(table, torch.zeros(1, 1, 3, 4)), torch.zeros(2, 2))
