"""The per-pixel sweep as truncated power series in s: what the fine bands sample through.

:mod:`prismstereo.epipolar.sweep` gives each reference pixel's correspondence m(s) (s linear in 1/Z) as a
Chebyshev polynomial of degree N - 1 (~1e-10 px); evaluating it costs N terms per sample.

:func:`sweep_series` truncates the same polynomials to the lowest degree D whose dropped Chebyshev terms stay
within ``tolerance_px`` at every pixel, as power series in s, planar per coordinate; :func:`series_at`
evaluates them at per-pixel coordinates by Horner's rule, 2 D multiply-adds per sample and coordinate and no
table lookups. With the default 2e-4 px over 228-1374 mm at 1024 x 768, ``thesis_setup1`` needs D = 4 (its
correspondences are nearly linear in s), ``thesis_setup2`` D = 8; evaluated in float32 the series stay within
3e-4 px of the float64 polynomials (``tests/epipolar/test_series.py``). The fine bands of
:class:`~prismstereo.matching.band.FineBand` sample through it: in onnxruntime 2 D multiply-adds per sample
instead of 4 gathers from a 53 MB table per band (and their index arithmetic). :func:`series_band` evaluates a
band of offsets around each pixel's s0 from the series' Taylor coefficients at s0 (multiply-adds on planes and
one matrix product instead of Horner's rule over the band's volume). ``benchmarks/onnx_speed.py`` times the
models that sample through them.
"""

from __future__ import annotations

import torch

from prismstereo.errors import OptionError, ShapeError, check_shape
from prismstereo.runtime import exporting

__all__ = ["series_at", "series_band", "sweep_series"]


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
    exported = exporting()
    if exported:
        vander = t.view(-1, 1) ** torch.arange(n + 1, device=s0.device).to(s0)  # (J, D + 1)
    t = t.view(1, -1, 1, 1)
    out = []
    for planes, shift in zip(series.to(s0).unbind(0), origin, strict=True):
        b = list(planes.unbind(0))  # c_0 .. c_D, each (H_s, W)
        b[0] = b[0] - shift
        for k in range(n):  # after pass k, b[k] is a_k (b[D] = c_D = a_D throughout)
            for i in range(n - 1, k - 1, -1):
                b[i] = b[i] + s0 * b[i + 1]
        if exported:  # (J, D + 1) @ (B, D + 1, H_s W): a MatMul (a 1 x 1 Conv became 16-channel NCHWc blocks)
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
