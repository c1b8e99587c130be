import pytest
import torch

from prismstereo import OptionError, ShapeError, thesis_setup1, thesis_setup2
from prismstereo.classical.model import PrismStereo
from prismstereo.epipolar.series import series_at, series_band, sweep_series
from prismstereo.epipolar.sweep import chebyshev_basis, fit_sweep, sweep_coefficients
from prismstereo.epipolar.sweep_table import column_to_sweep, cubic_at, local_cubic, tabulate_sweep, valid_interval
from prismstereo.matching.sweep_cost import warp_slices

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


@pytest.mark.parametrize("setup, degree", [(thesis_setup1, 4), (thesis_setup2, 8)])
def test_series_match_the_polynomials(setup, degree):
    """The truncated power series: the lowest degree whose dropped Chebyshev terms sum to <= 2e-4 px (setup 1 is
    nearly linear in s, setup 2 bends more), within that of the float64 polynomials in float64, and within ~3e-4
    px evaluated in float32 (rounding of positions up to ~1000 px); rows of the whole series as the fine band's
    strips evaluate them."""
    coef = _coefficients(setup().downscaled(2))
    series = sweep_series(coef)
    assert series.shape == (2, degree + 1, *coef.shape[1:3]) and series.dtype == F64
    assert sweep_series(coef, 1e-2).shape[1] < degree + 1 < sweep_series(coef, 1e-12).shape[1] <= coef.shape[0]
    gen = torch.Generator().manual_seed(5)
    s = torch.rand(2, 3, *coef.shape[1:3], generator=gen, dtype=F64) * 2 - 1
    exact = _exact(coef, s)
    x, y = series_at(series, s)
    assert x.shape == y.shape == s.shape
    assert float((torch.stack([x, y], -1) - exact).abs().max()) <= 2e-4
    x32, y32 = series_at(series.float(), s.float())
    assert x32.dtype == torch.float32
    assert float((torch.stack([x32, y32], -1).double() - exact).abs().max()) < 3e-4
    rows = series_at(series, s[..., 5:12, :], top=5)
    for a, b in zip(rows, (x, y), strict=True):
        assert torch.equal(a, b[..., 5:12, :])


@pytest.mark.parametrize("setup", [thesis_setup1, thesis_setup2])
def test_series_band_is_the_series_at_the_band(setup):
    """The band's positions from each pixel's Taylor coefficients at s0 are the series at s0 + t_j: to 1e-9 px in
    float64 (setups 1 / 2: degrees 4 / 8), within float32 rounding of positions up to ~1000 px of the float64
    polynomials (the tolerance of series_at), exact at t = 0 up to the origin; rows of the band are bitwise the
    rows of the whole one (the fine band's strips); the exported form (a MatMul with t_j^k) gives the same in
    onnxruntime."""
    import io

    import onnx
    import onnxruntime as ort

    coef = _coefficients(setup().downscaled(2))
    series = sweep_series(coef)
    gen = torch.Generator().manual_seed(6)
    s0 = torch.rand(2, 1, *coef.shape[1:3], generator=gen, dtype=F64) * 1.8 - 0.9
    offsets = torch.arange(-2, 3, dtype=F64) * 0.011
    x, y = series_band(series, s0, offsets)
    assert x.shape == y.shape == (2, 5, *coef.shape[1:3]) and x.dtype == F64
    hx, hy = series_at(series, s0 + offsets.view(1, -1, 1, 1))
    assert float((x - hx).abs().max()) < 1e-9 and float((y - hy).abs().max()) < 1e-9
    shifted = series_band(series, s0, offsets, origin=(100.0, -2.0))
    torch.testing.assert_close(shifted[0], x - 100.0)
    torch.testing.assert_close(shifted[1], y + 2.0)
    exact = _exact(coef, s0 + offsets.view(1, -1, 1, 1))
    x32, y32 = series_band(series.float(), s0.float(), offsets.float())
    assert x32.dtype == torch.float32
    assert float((torch.stack([x32, y32], -1).double() - exact).abs().max()) < 3e-4
    rows = series_band(series.float(), s0[..., 5:12, :].float(), offsets.float(), top=5)
    for a, b in zip(rows, (x32, y32), strict=True):
        assert torch.equal(a, b[..., 5:12, :])

    class Band(torch.nn.Module):
        def forward(self, t: torch.Tensor):
            return series_band(series.float(), t, offsets.float(), origin=(512.0, 0.0))

    f = io.BytesIO()
    torch.onnx.export(Band(), (s0[:1].float(),), f, opset_version=18, dynamo=False, input_names=["s0"])
    assert "MatMul" in {n.op_type for n in onnx.load_from_string(f.getvalue()).graph.node}
    session = ort.InferenceSession(f.getvalue(), providers=["CPUExecutionProvider"])
    ox, oy = session.run(None, {"s0": s0[:1].float().numpy()})
    torch.testing.assert_close(torch.from_numpy(ox), x32[:1] - 512.0, rtol=0, atol=3e-4)
    torch.testing.assert_close(torch.from_numpy(oy), y32[:1], rtol=0, atol=3e-4)


def test_series_band_reference_values_gradient_and_errors():
    # x = 0.5 + 2 s + s^2, y = 3 s (as in the series test below), a band around s0 = 0.5
    series = sweep_series(torch.tensor([[1.0, 0.0], [2.0, 3.0], [0.5, 0.0]], dtype=F64).view(3, 1, 1, 2))
    x, y = series_band(series, torch.full((1, 1, 1, 1), 0.5, dtype=F64), torch.tensor([-0.5, 0.0, 1.0], dtype=F64))
    assert x.flatten().tolist() == [0.5, 1.75, 5.75] and y.flatten().tolist() == [0.0, 1.5, 4.5]
    constant = torch.tensor([[7.0, -1.0]], dtype=F64).view(2, 1, 1, 1)  # degree 0: the same at every offset
    cx, cy = series_band(constant, torch.zeros(3, 1, 1, 1, dtype=F64), torch.tensor([-1.0, 1.0], dtype=F64))
    assert cx.shape == (3, 2, 1, 1) and bool((cx == 7.0).all()) and bool((cy == -1.0).all())
    s0 = torch.rand(2, 1, 1, 1, generator=torch.Generator().manual_seed(2), dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: series_band(series, t, torch.tensor([-0.1, 0.2], dtype=F64)), (s0,))
    with pytest.raises(ShapeError, match="s0"):
        series_band(series, torch.zeros(1, 2, 1, 1, dtype=F64), torch.zeros(3, dtype=F64))
    with pytest.raises(ShapeError, match="offsets"):
        series_band(series, torch.zeros(1, 1, 1, 1, dtype=F64), torch.zeros(1, 3, dtype=F64))
    with pytest.raises(ShapeError, match="no rows"):
        series_band(series, torch.zeros(1, 1, 1, 1, dtype=F64), torch.zeros(3, dtype=F64), top=1)


def test_series_reference_values_and_gradient():
    # T_0 + 2 T_1 + 0.5 T_2 = 1 + 2 s + 0.5 (2 s^2 - 1) = 0.5 + 2 s + s^2 in x; y = 3 T_1 = 3 s
    coef = torch.tensor([[1.0, 0.0], [2.0, 3.0], [0.5, 0.0]], dtype=F64).view(3, 1, 1, 2)
    series = sweep_series(coef)
    torch.testing.assert_close(series[:, :, 0, 0], torch.tensor([[0.5, 2.0, 1.0], [0.0, 3.0, 0.0]], dtype=F64))
    x, y = series_at(series, torch.tensor([0.5], dtype=F64).view(1, 1, 1, 1))
    assert float(x) == 0.5 + 1.0 + 0.25 and float(y) == 1.5
    assert sweep_series(coef, 0.6).shape[1] == 2  # dropping 0.5 T_2 is within 0.6 px: a line
    s = torch.rand(1, 2, 1, 1, generator=torch.Generator().manual_seed(1), dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: series_at(series, t), (s,))


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
    model = PrismStereo(rig, (228.0, 1374.0), dict(coarse_factor=1))
    table = tabulate_sweep(_coefficients(rig))
    lo, hi = valid_interval(table, model.final.other_valid, model.split.split)
    gen = torch.Generator().manual_seed(2)
    s = torch.rand(1, 16, *table.shape[1:3], generator=gen, dtype=F64) * 2 - 1
    cubic = local_cubic(table, s.reshape(16, 1, *table.shape[1:3]))
    xy = cubic_at(cubic, cubic.u)[:, 0].unsqueeze(0)  # (1, 16, H, W, 2) full-sensor pixels
    h, w_o = rig.image_height, rig.image_width - model.split.split
    grid = torch.stack([(2 * (xy[..., 0] - model.split.split) + 1) / w_o - 1, (2 * xy[..., 1] + 1) / h - 1], -1)
    sampled = warp_slices(torch.zeros(1, 1, h, w_o, dtype=F64), grid, model.final.other_valid).valid
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
    with pytest.raises(ShapeError, match="series must have shape"):
        series_at(torch.zeros(3, 2, 3, 4), torch.zeros(1, 1, 3, 4))
    with pytest.raises(ShapeError, match="no rows 2..3"):
        series_at(torch.zeros(2, 2, 3, 4), torch.zeros(1, 1, 2, 4), top=2)
    with pytest.raises(ShapeError, match="of width 5"):
        series_at(torch.zeros(2, 2, 3, 4), torch.zeros(1, 1, 3, 5))
    with pytest.raises(OptionError, match="tolerance_px must be > 0"):
        sweep_series(torch.zeros(5, 3, 4, 2), -1.0)
    with pytest.raises(ShapeError, match="coefficients"):
        sweep_series(torch.zeros(5, 3, 4))
