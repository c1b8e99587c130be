"""The per-pixel sweep tabulated at a few uniform coordinates: local cubics, inversion, valid intervals.

:func:`tabulate_sweep` tabulates each reference pixel's correspondence m(s) (:mod:`prismstereo.epipolar.sweep`)
at K uniform coordinates; the 4 entries around s give a local cubic (:func:`local_cubic`; Lagrange through
u = -1, 0, 1, 2 in table units). K is the smallest of 17, 33, 65 keeping the cubics within ``tolerance_px`` of
the polynomial: measured over 205-1511 mm at full resolution, K = 17 gives 4e-6 px for ``thesis_setup1``,
K = 33 gives 7e-4 px for ``thesis_setup2`` (whose correspondences bend more; K = 65: 5e-5 px).
:func:`column_to_sweep` inverts it (Newton on the cubics): a rectified disparity (a column) -> s.

:func:`valid_interval` finds, per reference pixel, the interval [s_lo, s_hi] of coordinates whose sample has
every bilinear tap inside the other half on a pixel that sees through the prism (the test of
:func:`~prismstereo.matching.sweep_cost.warp_slices`), so a band's validity is two comparisons instead of a
second sampled channel.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from prismstereo.epipolar.sweep import positions_at
from prismstereo.errors import OptionError, ShapeError, check_shape
from prismstereo.runtime import exporting, sample_bilinear

__all__ = [
    "LocalCubic", "TABLE_SIZES", "column_to_sweep", "cubic_at", "local_cubic", "tabulate_sweep", "valid_interval",
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
            in an ONNX export a slice of the table is a constant-folded copy (row strips would store the table
            again, about once more in all).

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
    if exporting():
        # element gathers of x and y from the flat table: onnxruntime's GatherElements runs a typed loop where
        # its Gather of (x, y) rows makes one memcpy per row, the slower of the two there; no broadcast along the
        # trailing axis, slow in onnxruntime
        base = torch.stack([2 * base, 2 * base + 1], -1)
        flat = table.reshape(-1)
        taps = [flat.gather(0, (base + o * h * w * 2).reshape(-1)) for o in (-1, 0, 1, 2)]
    else:  # torch: rows are the faster of the two
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
    axis of 1 against one of n far more slowly than two equal shapes (its Expand is as slow), so the coordinate
    pairs are multiplied by a u of the same shape."""
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
        seen = sample_bilinear(mask.expand(xy.shape[0], -1, -1, -1), x.unsqueeze(1), y.unsqueeze(1))[:, 0, 0] > 0.999
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
