"""The per-pixel sweep in forms that are fast to evaluate: a power series for the fine band's samples, a
table for inverting it, and the interval of s where a reference pixel's correspondence is a real
other-half sample.

:mod:`prismstereo.epipolar.sweep` gives each reference pixel's correspondence m(s) (s linear in 1/Z) as a
Chebyshev polynomial of degree N - 1 (~1e-10 px); evaluating it costs N terms per sample.

* :func:`sweep_series`: the same polynomials truncated to the lowest degree D whose dropped Chebyshev terms
  stay within ``tolerance_px`` at every pixel, as power series in s, planar per coordinate; :func:`series_at`
  evaluates them at per-pixel coordinates by Horner's rule, 2 D multiply-adds per sample and coordinate
  and no table lookups. With the default 2e-4 px over 228-1374 mm at 1024 x 768, ``thesis_setup1`` needs D = 4
  (its correspondences are nearly linear in s), ``thesis_setup2`` D = 8; float32 evaluation adds ~6e-5 px of
  rounding (measured against the float64 polynomials on every 3rd pixel at 5 random s each: 1.4e-4 / 2.5e-4 px
  in all). The fine bands of :class:`~prismstereo.matching.levels.FineBand` sample through it; in onnxruntime
  that replaced 4 gathers from a 53 MB table per band (and their index arithmetic) by 2 D multiply-adds per
  sample, the full-resolution band of 3 alone 0.75x its time. :func:`series_band` evaluates a band of offsets
  around each pixel's s0 from the series' Taylor coefficients at s0 (multiply-adds on planes and one matrix
  product instead of Horner's rule over the band's volume): the narrow-range pyramid (600-1450 mm, 1024 x 768)
  0.96-0.97x its onnxruntime time (paired A/B).
* :func:`tabulate_sweep`: m tabulated at K uniform coordinates; the 4 entries around s give a local cubic
  (:func:`local_cubic`; Lagrange through u = -1, 0, 1, 2 in table units). K is the smallest of 17, 33, 65
  keeping the cubics within ``tolerance_px`` of the polynomial: measured over 205-1511 mm at full
  resolution, K = 17 gives 4e-6 px for ``thesis_setup1``, K = 33 gives 7e-4 px for ``thesis_setup2`` (whose
  correspondences bend more; K = 65: 5e-5 px). :func:`column_to_sweep` inverts it (Newton on the cubics).

:func:`valid_interval` finds, per reference pixel, the interval [s_lo, s_hi] of coordinates whose sample has
every bilinear tap inside the other half on a pixel that sees through the prism (the test of
:func:`~prismstereo.matching.sweep_cost.warp_slices`), so a band's validity is two comparisons instead of a
second sampled channel.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
import torch.nn.functional as F

from prismstereo.epipolar.sweep import chebyshev_basis
from prismstereo.errors import OptionError, ShapeError, check_shape

__all__ = [
    "LocalCubic", "TABLE_SIZES", "column_to_sweep", "cubic_at", "local_cubic", "positions_at", "series_at",
    "series_band", "sweep_hypotheses", "sweep_series", "tabulate_sweep", "valid_interval",
]

TABLE_SIZES = (17, 33, 65)  # candidate numbers of tabulated coordinates (2^k + 1)


class LocalCubic(NamedTuple):
    """Each pixel's correspondence near its coordinate s, as a cubic in the local table variable u.

    Attributes:
        coefficients: (4, B, 1, H, W, 2) monomial coefficients c_0..c_3 of m(u) = sum c_k u^k.
        u: (B, 1, H, W) the pixels' own coordinates in table units (u = 0 and 1 at the bracketing entries;
            in [-1, 2] near the table's ends).
        scale: du/ds = (K - 1) / 2.
    """

    coefficients: torch.Tensor
    u: torch.Tensor
    scale: float


def positions_at(coefficients: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """Per-pixel sweep polynomials at coordinates shared by all pixels, by one matrix product.

    Args:
        coefficients: (N, H, W, 2) per-pixel Chebyshev coefficients in s.
        s: (S,) coordinates in [-1, 1].

    Returns:
        (S, H, W, 2) positions, dtype of ``coefficients``.

    Example:
        >>> positions_at(torch.ones(3, 4, 5, 2), torch.tensor([1.0, 0.0])).shape
        torch.Size([2, 4, 5, 2])
    """
    check_shape(coefficients, ["N", "H", "W", 2], "coefficients")
    n = coefficients.shape[0]
    basis = chebyshev_basis(s.to(coefficients), n)  # (S, N)
    return (basis @ coefficients.reshape(n, -1)).view(-1, *coefficients.shape[1:])


def sweep_hypotheses(coefficients: torch.Tensor, max_step_px: float = 1.0) -> int:
    """Number of hypotheses, uniform in s over [-1, 1], with neighbours at most ``max_step_px`` apart in
    the other half for every pixel of the per-pixel sweep polynomials ``coefficients`` (N, H, W, 2).

    Example:
        >>> from prismstereo.epipolar.sweep import fit_sweep, sweep_coefficients
        >>> rig = thesis_setup1().downscaled(8); fit = fit_sweep(rig, (400.0, 700.0))
        >>> uv = torch.stack(torch.meshgrid(torch.arange(64.0), torch.arange(96.0), indexing="xy"), -1)
        >>> coef = sweep_coefficients(fit, uv.double()).permute(2, 0, 1, 3)
        >>> sweep_hypotheses(coef) >= 10
        True
    """
    if max_step_px <= 0:
        raise OptionError(f"max_step_px must be > 0, got {max_step_px}")
    probe = torch.linspace(-1.0, 1.0, 257, dtype=coefficients.dtype, device=coefficients.device)
    sub = coefficients[:, ::4, ::4]
    pos = positions_at(sub, probe)  # (257, h, w, 2)
    speed = (pos[1:] - pos[:-1]).norm(dim=-1).amax() * 256 / 2  # px per unit s (max over pixels)
    return max(2, math.ceil(float(speed) * 2 / max_step_px * 1.02) + 1)


def _chebyshev_to_power(n: int, like: torch.Tensor) -> torch.Tensor:
    """(n, n) matrix M with M[k, m] the coefficient of s^k in T_m(s)."""
    out = torch.zeros(n, n, dtype=like.dtype, device=like.device)
    out[0, 0] = 1.0
    if n > 1:
        out[1, 1] = 1.0
    for m in range(2, n):  # T_m = 2 s T_{m-1} - T_{m-2}
        out[1:, m] = 2 * out[:-1, m - 1]
        out[:, m] -= out[:, m - 2]
    return out


def sweep_series(coefficients: torch.Tensor, tolerance_px: float = 2e-4) -> torch.Tensor:
    """Per-pixel sweep polynomials as power series in s of the lowest degree within a tolerance.

    The Chebyshev series is truncated after degree D, the smallest whose dropped terms sum to at most
    ``tolerance_px`` in absolute value at every pixel and for both coordinates (a bound on the truncation
    error over s in [-1, 1], since |T_k| <= 1), and re-expanded in powers of s (float64).

    Args:
        coefficients: (N, H, W, 2) per-pixel Chebyshev coefficients in s (pixels), e.g.
            ``sweep_coefficients(fit, uv).permute(2, 0, 1, 3)``.
        tolerance_px: bound on the truncation error (> 0); the full degree N - 1 when no lower one meets it.

    Returns:
        (2, D + 1, H, W) coefficients of s^0 .. s^D of the x (first) and y positions, dtype of ``coefficients``.

    Raises:
        ShapeError: bad shape. OptionError: tolerance not > 0.

    Example:
        >>> from prismstereo.epipolar.sweep import fit_sweep, sweep_coefficients
        >>> uv = torch.stack(torch.meshgrid(torch.arange(8.0), torch.arange(6.0), indexing="xy"), -1).double()
        >>> coef = sweep_coefficients(fit_sweep(thesis_setup1(), (300.0, 900.0)), uv).permute(2, 0, 1, 3)
        >>> sweep_series(coef).shape  # a cubic in s is within 2e-4 px here
        torch.Size([2, 4, 6, 8])
    """
    check_shape(coefficients, ["N", "H", "W", 2], "coefficients")
    if not tolerance_px > 0:
        raise OptionError(f"tolerance_px must be > 0, got {tolerance_px}")
    n = coefficients.shape[0]
    dropped = coefficients.abs().flip(0).cumsum(0).flip(0)  # dropped[k]: sum of |c_m| over m >= k
    bound = dropped.flatten(1).amax(1)  # (N,) worst pixel and coordinate
    degree = next((d for d in range(n - 1) if bound[d + 1] <= tolerance_px), n - 1)
    power = _chebyshev_to_power(n, coefficients)[:degree + 1, :degree + 1]  # (D + 1, D + 1)
    kept = coefficients[:degree + 1].permute(3, 0, 1, 2)  # (2, D + 1, H, W)
    return torch.einsum("km,cmhw->ckhw", power, kept).contiguous()


def series_at(series: torch.Tensor, s: torch.Tensor, top: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Evaluate :func:`sweep_series` at per-pixel coordinates by Horner's rule.

    Args:
        series: (2, D + 1, H, W) from :func:`sweep_series`.
        s: (B, J, H_s, W) coordinates (J per pixel) of the series' rows ``top`` ... ``top + H_s - 1`` (all of
            them by default); differentiable.
        top: the series row of s's first row.

    Returns:
        (x, y), each (B, J, H_s, W) positions (units of the series: full-sensor pixels).

    Raises:
        ShapeError: bad shapes or rows outside the series.

    Example:
        >>> series = torch.tensor([[1.0, 2.0], [0.0, 0.5]]).view(2, 2, 1, 1)  # x = 1 + 2 s, y = s / 2
        >>> x, y = series_at(series, torch.tensor([0.0, 0.5]).view(1, 2, 1, 1))
        >>> x.flatten().tolist(), y.flatten().tolist()
        ([1.0, 2.0], [0.0, 0.25])
    """
    check_shape(series, [2, "K", "H", "W"], "series")
    check_shape(s, ["B", "J", "H_s", "W"], "s")
    series = _rows_of(series, s, top)
    out = []
    for planes in series.to(s).unbind(0):  # (D + 1, H_s, W) per coordinate
        acc = planes[-1].expand_as(s) if planes.shape[0] == 1 else planes[-1] * s + planes[-2]
        for k in range(planes.shape[0] - 3, -1, -1):
            acc = acc * s + planes[k]
        out.append(acc)
    return out[0], out[1]


def series_band(series: torch.Tensor, s0: torch.Tensor, offsets: torch.Tensor, top: int = 0,
                origin: tuple[float, float] = (0.0, 0.0)) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`series_at` at s0 + t_j for every pixel and a band of offsets t_j shared by all pixels.

    Each pixel's series is re-expanded about its own s0: p(s0 + t) = sum_k a_k t^k with
    a_k = sum_{i >= k} C(i, k) c_i s0^(i - k) (the Taylor coefficients, by repeated synthetic division: D (D + 1) / 2
    multiply-adds over (B, 1, H, W) planes per coordinate), and the J positions are then one product with the
    (J, D + 1) matrix t_j^k: in an ONNX export one MatMul (a 1 x 1 Conv became 16-channel NCHWc blocks in
    onnxruntime), where Horner's rule at each s0 + t_j takes 2 D passes over (B, J, H, W) volumes. Torch eager
    evaluates sum_k a_k t^k by Horner's rule in t instead (element by element, so a band's rows give the same bits
    whichever rows are computed with them; oneDNN's convolution did not). The same numbers as
    ``series_at(series, s0 + t)`` up to float rounding.

    Args:
        series: (2, D + 1, H, W) from :func:`sweep_series`.
        s0: (B, 1, H_s, W) each pixel's centre coordinate, rows ``top`` ... of the series; differentiable.
        offsets: (J,) the band's offsets t_j in s.
        top: the series row of s0's first row.
        origin: (x, y) subtracted from the positions (e.g. the other half's first column).

    Returns:
        (x, y), each (B, J, H_s, W) positions (units of the series, minus ``origin``).

    Raises:
        ShapeError: bad shapes or rows outside the series.

    Example:
        >>> series = torch.tensor([[1.0, 2.0, 3.0], [0.0, 0.5, 0.0]]).view(2, 3, 1, 1)  # x = 1 + 2 s + 3 s^2
        >>> x, y = series_band(series, torch.full((1, 1, 1, 1), 0.5), torch.tensor([-0.5, 0.0, 0.5]))
        >>> x.flatten().tolist(), y.flatten().tolist()
        ([1.0, 2.75, 6.0], [0.0, 0.25, 0.5])
    """
    check_shape(series, [2, "K", "H", "W"], "series")
    check_shape(s0, ["B", 1, "H_s", "W"], "s0")
    check_shape(offsets, ["J"], "offsets")
    series = _rows_of(series, s0, top)
    n = series.shape[1] - 1
    t = offsets.to(s0)
    exporting = torch.onnx.is_in_onnx_export()
    if exporting:
        vander = t.view(-1, 1) ** torch.arange(n + 1, device=s0.device).to(s0)  # (J, D + 1)
    t = t.view(1, -1, 1, 1)
    out = []
    for planes, shift in zip(series.to(s0).unbind(0), origin, strict=True):
        b = list(planes.unbind(0))  # c_0 .. c_D, each (H_s, W)
        b[0] = b[0] - shift
        for k in range(n):  # after pass k, b[k] is a_k (b[D] = c_D = a_D throughout)
            for i in range(n - 1, k - 1, -1):
                b[i] = b[i] + s0 * b[i + 1]
        if exporting:  # (J, D + 1) @ (B, D + 1, H_s W): a MatMul (a 1 x 1 Conv became 16-channel NCHWc blocks)
            b[n] = b[n].expand_as(s0)
            a = torch.cat(b, 1).flatten(2)
            out.append(torch.matmul(vander, a).view(s0.shape[0], -1, *s0.shape[2:]))
            continue
        acc = b[n] * t + b[n - 1] if n else b[0] + torch.zeros_like(t)
        for k in range(n - 2, -1, -1):
            acc = acc * t + b[k]
        out.append(acc.expand(s0.shape[0], -1, -1, -1) if acc.shape[0] != s0.shape[0] else acc)
    return out[0], out[1]


def _rows_of(series: torch.Tensor, s: torch.Tensor, top: int) -> torch.Tensor:
    """The rows ``top`` ... of ``series`` (2, D + 1, H, W) that the coordinates ``s`` (..., H_s, W) cover."""
    h, w = series.shape[-2:]
    rows = s.shape[-2]
    if s.shape[-1] != w or not 0 <= top <= h - rows:
        raise ShapeError(f"series {tuple(series.shape)} has no rows {top}..{top + rows - 1} of width {s.shape[-1]}")
    return series[..., top:top + rows, :] if top or rows != h else series


def tabulate_sweep(coefficients: torch.Tensor, tolerance_px: float = 1e-3) -> torch.Tensor:
    """Tabulate per-pixel sweep polynomials at K uniform coordinates over [-1, 1].

    Args:
        coefficients: (N, H, W, 2) per-pixel Chebyshev coefficients in s (pixels), e.g.
            ``sweep_coefficients(fit, uv).permute(2, 0, 1, 3)``.
        tolerance_px: K is the smallest of :data:`TABLE_SIZES` whose local cubics stay within this of the
            polynomials (checked in float64 on every 8th pixel at 64 seeded random coordinates); the largest
            otherwise.

    Returns:
        (K, H, W, 2) positions, dtype of ``coefficients``.

    Example:
        >>> from prismstereo.epipolar.sweep import fit_sweep, sweep_coefficients
        >>> uv = torch.stack(torch.meshgrid(torch.arange(8.0), torch.arange(6.0), indexing="xy"), -1).double()
        >>> coef = sweep_coefficients(fit_sweep(thesis_setup1(), (300.0, 900.0)), uv).permute(2, 0, 1, 3)
        >>> tabulate_sweep(coef).shape
        torch.Size([17, 6, 8, 2])
    """
    check_shape(coefficients, ["N", "H", "W", 2], "coefficients")
    if not tolerance_px > 0:
        raise OptionError(f"tolerance_px must be > 0, got {tolerance_px}")
    probe = coefficients[:, ::8, ::8].to(torch.float64)
    s = torch.rand(64, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 2 - 1
    exact = positions_at(probe, s).unsqueeze(1)  # (64, 1, h, w, 2)
    for k in TABLE_SIZES:
        small = positions_at(probe, torch.linspace(-1.0, 1.0, k, dtype=torch.float64))
        cubic = local_cubic(small, s.view(-1, 1, 1, 1).expand(-1, 1, *probe.shape[1:3]))
        if (cubic_at(cubic, cubic.u) - exact).norm(dim=-1).amax() <= tolerance_px:
            break
    return positions_at(coefficients, torch.linspace(-1.0, 1.0, k, dtype=torch.float64))


def local_cubic(table: torch.Tensor, s: torch.Tensor, top: int = 0) -> LocalCubic:
    """The cubic through the 4 table entries around each pixel's coordinate.

    Args:
        table: (K, H, W, 2) from :func:`tabulate_sweep` (any affine image of it, e.g. grid_sample units).
        s: (B, 1, H_s, W) coordinates in [-1, 1] (clamp first) of the table's rows ``top`` ... ``top + H_s - 1``
            (all of them by default); gradients flow through the cubic's u.
        top: the table row of s's first row. A band of rows indexes the whole table instead of a slice of it:
            in an ONNX export a slice of the table is a constant-folded copy (4 row strips stored the 53 MB
            table of ``thesis_setup1`` ~1.9 times).

    Returns:
        LocalCubic.

    Example:
        >>> table = torch.linspace(-1.0, 1.0, 17).pow(2).view(17, 1, 1, 1).expand(17, 1, 1, 2)
        >>> c = local_cubic(table, torch.tensor([0.3]).view(1, 1, 1, 1))
        >>> round(float(cubic_at(c, c.u)[0, 0, 0, 0, 0]), 6)
        0.09
    """
    check_shape(table, ["K", "H", "W", 2], "table")
    check_shape(s, ["B", 1, "H_s", "W"], "s")
    k, h, w, _ = table.shape
    rows = s.shape[-2]
    if k < 4 or s.shape[-1] != w or not 0 <= top <= h - rows:
        raise ShapeError(f"table {tuple(table.shape)} needs K >= 4 and the pixels of s {tuple(s.shape)} "
                         f"from row {top}")
    b = s.shape[0]
    scale = (k - 1) / 2
    t = (s + 1.0) * scale
    i = t.detach().floor().clamp(1, k - 3)
    u = t - i
    pixels = torch.arange(top * w, (top + rows) * w, device=s.device).view(1, 1, rows, w)
    base = i.long() * (h * w) + pixels  # flat index of entry i
    if torch.onnx.is_in_onnx_export():
        # element gathers of x and y from the flat table: onnxruntime's GatherElements runs a typed loop where
        # its Gather of (x, y) rows makes one memcpy per row (2.0 against 4.5 ms for 242 k pixels; a 1024 x 768
        # frame ~8 ms faster); no broadcast along the trailing axis, slow in onnxruntime
        base = torch.stack([2 * base, 2 * base + 1], -1)
        flat = table.reshape(-1)
        taps = [flat.gather(0, (base + o * h * w * 2).reshape(-1)) for o in (-1, 0, 1, 2)]
    else:  # torch: rows are faster (0.84 against 1.10 ms on 120 x 512 pixels)
        flat = table.reshape(k * h * w, 2)
        taps = [flat.index_select(0, (base + o * h * w).reshape(-1)) for o in (-1, 0, 1, 2)]
    pm, p0, p1, p2 = (t.view(b, 1, rows, w, 2) for t in taps)
    coefficients = torch.stack([p0, p1 - pm / 3 - p0 / 2 - p2 / 6, (pm + p1) / 2 - p0, (p2 - pm) / 6 + (p0 - p1) / 2])
    return LocalCubic(coefficients, u, scale)


def cubic_at(cubic: LocalCubic, u: torch.Tensor) -> torch.Tensor:
    """Evaluate a :class:`LocalCubic` at local coordinates u (B, J, H, W) -> (B, J, H, W, 2).

    Example:
        >>> c = LocalCubic(torch.ones(4, 1, 1, 1, 1, 2), torch.zeros(1, 1, 1, 1), 8.0)
        >>> cubic_at(c, torch.full((1, 1, 1, 1), 2.0))[0, 0, 0, 0].tolist()
        [15.0, 15.0]
    """
    c = cubic.coefficients
    x = _lanes(u, c.shape[-1])
    return c[0] + x * (c[1] + x * (c[2] + x * c[3]))


def _lanes(u: torch.Tensor, n: int) -> torch.Tensor:
    """``u`` (...) as (..., n): n copies along a new last axis, by one Concat. onnxruntime multiplies a trailing
    axis of 1 against one of n slowly (a (1, 1, 768, 512, 1) x (..., 2) Mul: 2.1 ms, equal shapes 0.07 ms; its
    Expand is as slow), so the coordinate pairs are multiplied by a u of the same shape."""
    x = u.unsqueeze(-1)
    return torch.cat([x] * n, -1) if n > 1 else x


def column_to_sweep(table: torch.Tensor, column: torch.Tensor, iterations: int = 3) -> torch.Tensor:
    """Per pixel, the coordinate s whose correspondence lies on a given column: m_x(s) = column.

    m_x is monotone in s (the disparity); the start is the linear interpolation between the table's ends,
    then Newton steps on the local cubics (:func:`local_cubic`); s is clamped to [-1, 1] (columns beyond the
    searched range give its end). Used to turn a rectified disparity (a column shift,
    :mod:`prismstereo.epipolar.row_rectify`) into the sweep coordinate (and so the depth).

    Args:
        table: (K, H, W, 2) :func:`tabulate_sweep` (full-sensor pixels).
        column: (B, 1, H, W) target columns m_x (full-sensor pixels).
        iterations: Newton steps (3 reach ~1e-6 px on the thesis rigs).

    Returns:
        (B, 1, H, W) s in [-1, 1], differentiable w.r.t. ``column``.

    Example:
        >>> table = torch.stack([torch.linspace(0.0, 64.0, 17) ** 1.1, torch.zeros(17)], -1).view(17, 1, 1, 2)
        >>> s = column_to_sweep(table, torch.tensor([30.0]).view(1, 1, 1, 1))
        >>> round(float(cubic_at(local_cubic(table, s), local_cubic(table, s).u)[0, 0, 0, 0, 0]), 4)
        30.0
    """
    check_shape(table, ["K", "H", "W", 2], "table")
    check_shape(column, ["B", 1, "H", "W"], "column")
    first, last = table[0, ..., 0], table[-1, ..., 0]
    span = last - first
    span = torch.where(span.abs() > 1e-9, span, torch.ones_like(span))
    s = (2.0 * (column - first) / span - 1.0).clamp(-1.0, 1.0)
    for _ in range(iterations):
        cubic = local_cubic(table, s)
        c0, c1, c2, c3 = cubic.coefficients[..., 0].unbind(0)
        u = cubic.u
        value = c0 + u * (c1 + u * (c2 + u * c3))
        slope = (c1 + u * (2 * c2 + 3 * u * c3)) * cubic.scale  # dm_x / ds
        slope = torch.where(slope.abs() > 1e-9, slope, torch.ones_like(slope))
        s = (s - (value - column) / slope).clamp(-1.0, 1.0)
    return s


def valid_interval(table: torch.Tensor, other_valid: torch.Tensor, split: int, steps: int = 14) -> torch.Tensor:
    """Per reference pixel, the interval [s_lo, s_hi] of coordinates whose correspondence is a real sample of
    the other half: inside it (all bilinear taps between its first and last pixel centres, 1e-3 px slack) on
    pixels that see through the prism (``other_valid``).

    The largest contiguous valid run of the table's K coordinates is refined at both ends by ``steps``
    bisections on the local cubics (to 2 / (K - 1) / 2^steps in s); pixels with no valid table entry get an
    empty interval (s_lo = 2 > s_hi = -2). Valid sets that are not one interval (a hole in ``other_valid``
    along the curve) keep their largest run: the interval never contains a coordinate found invalid.

    Args:
        table: (K, H, W, 2) :func:`tabulate_sweep` in full-sensor pixels.
        other_valid: (H_o, W_o) bool mask of the other half.
        split: the other half's first full-sensor column.
        steps: bisection steps per end.

    Returns:
        (2, H, W) [s_lo, s_hi], dtype of ``table``.

    Example:
        >>> table = torch.stack([torch.linspace(0.0, 40.0, 17) + 20, torch.zeros(17)], -1).view(17, 1, 1, 2)
        >>> lo, hi = valid_interval(table, torch.ones(1, 30, dtype=torch.bool), 20)
        >>> round(float(lo), 3), round(float(hi), 3)
        (-1.0, 0.45)
    """
    check_shape(table, ["K", "H", "W", 2], "table")
    check_shape(other_valid, ["H", "W"], "other_valid")
    if not isinstance(steps, int) or steps < 0:
        raise OptionError(f"steps must be an int >= 0, got {steps!r}")
    h_o, w_o = other_valid.shape
    mask = other_valid.to(table)[None, None]
    eps = 1e-3

    def real(xy: torch.Tensor) -> torch.Tensor:  # (S, H, W, 2) full-sensor positions -> (S, H, W) bool
        x, y = xy[..., 0] - split, xy[..., 1]
        inside = (x >= -eps) & (x <= w_o - 1 + eps) & (y >= -eps) & (y <= h_o - 1 + eps)
        grid = torch.stack([(2 * x + 1) / w_o - 1, (2 * y + 1) / h_o - 1], -1)
        seen = F.grid_sample(mask.expand(xy.shape[0], -1, -1, -1), grid, mode="bilinear", padding_mode="border",
                             align_corners=False)[:, 0] > 0.999
        return inside & seen

    k, h, w, _ = table.shape
    good = real(table)  # (K, H, W): the table's own coordinates
    run = torch.zeros(h, w, dtype=torch.long, device=table.device)
    best_len, best_end = torch.zeros_like(run), torch.full_like(run, -1)
    for i in range(k):  # longest run of consecutive valid entries per pixel
        run = torch.where(good[i], run + 1, torch.zeros_like(run))
        longer = run > best_len
        best_len, best_end = torch.where(longer, run, best_len), torch.where(longer, torch.full_like(run, i), best_end)
    first, last = best_end - best_len + 1, best_end
    step = 2.0 / (k - 1)
    inner = torch.stack([first, last]).clamp_min(0).to(table.dtype) * step - 1.0  # valid ends (2, H, W)
    outer = inner + torch.tensor([-step, step], dtype=table.dtype, device=table.device).view(2, 1, 1)
    for _ in range(steps):  # bisect both ends at once; coordinates beyond [-1, 1] count as invalid
        mid = (inner + outer) / 2
        cubic = local_cubic(table, mid.clamp(-1.0, 1.0).unsqueeze(1))
        ok = real(cubic_at(cubic, cubic.u)[:, 0]) & (mid.abs() <= 1.0)
        inner, outer = torch.where(ok, mid, inner), torch.where(ok, outer, mid)
    found = best_len > 0
    return torch.stack([torch.where(found, inner[0], torch.full_like(inner[0], 2.0)),
                        torch.where(found, inner[1], torch.full_like(inner[1], -2.0))])
