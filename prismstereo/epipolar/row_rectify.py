"""Row rectification of the two half-images by vertical warps, fitted to the exact sweep.

Pinhole rectification (:mod:`prismstereo.analysis.pinhole_rectify`, Fusiello) leaves true correspondences up to
0.9 px (``thesis_setup1``) and 12 px (``thesis_setup2``) apart vertically: the bi-prism's virtual cameras are
not pinholes. Here the rectification is fitted to the exact correspondences instead. Both halves keep their
columns and are only warped vertically: reference pixel (u, v) goes to rectified row

    R_ref(u, v) = v + a(u, v),          a(u, v) = sum_{i >= 1, j} A[i, j] (T_i(x(u)) - T_i(0)) T_j(y(v)),

and other-half pixel (X, Y) (full-sensor column X) to

    R_oth(X, Y) = Y + b(X, Y),          b(X, Y) = sum_{i, j} B[i, j] T_i(x_o(X)) T_j(y(Y)),

with Chebyshev polynomials T of the normalised coordinates x(u) = 2 (u + 0.5) / W_ref - 1,
x_o(X) = 2 (X - W_ref + 0.5) / W_o - 1, y(v) = 2 (v + 0.5) / H - 1. A and B solve one linear least-squares
problem, R_ref(u, v) = R_oth(m(u, v, s)), over the exact sweep m (:mod:`prismstereo.epipolar.sweep`, the
correspondence of reference pixel (u, v) at sweep coordinate s; thesis eq. 4.1-4.10 approximate its curve
by a line) on a pixel grid times a set of depths; a(., .) vanishes on the reference half's centre column
(the gauge: any common function of the row could be added to both). After the warps, a reference pixel and
its correspondences at every depth share one row, and disparity is a pure column shift: the matcher
builds a 1-D cost volume by shifts (:class:`~prismstereo.classical.model.PrismStereo` with ``sampling='rectified'``).

The residual |R_ref - R_oth(m)| is what the bi-prism's non-central rays leave (no row warp can remove it).
Measured over 228-1374 mm at full resolution, degree 4 (every 8th pixel, 33 depths, co-visible samples):
``thesis_setup1`` 1.6e-4 px max (rms 2.6e-5 px), ``thesis_setup2`` 0.099 px max (rms 0.013 px); degree 2
gives 0.008 / 0.53 px, degree 6 no better than 4. The warps themselves reach 1.5 px (setup 1) and 8-12 px
(setup 2) at the corners.
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

import torch
import torch.nn.functional as F

from prismstereo.epipolar.sweep import SweepFit, chebyshev_basis, positions_at, sweep_coefficients
from prismstereo.epipolar.sweep_table import tabulate_sweep
from prismstereo.errors import OptionError, RigError, check_option
from prismstereo.geometry.optics import trace_pixels
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.threads import torch_threads

__all__ = ["RectifiedLevel", "RowRectification", "fit_row_rectification", "level_coverage", "rectified_level",
           "rectified_rows", "source_rows"]

Side = Literal["reference", "other"]
SIDES: tuple[str, ...] = ("reference", "other")


class RectifiedLevel(NamedTuple):
    """How one pyramid level (box-downsampled by f) is matched in rectified coordinates.

    Level pixel (r_c, u_c) of the rectified reference stands for column u = (u_c + 0.5) f - 0.5 and rectified
    row r = first_row + (r_c + 0.5) f - 0.5; shift k compares it with column u_c + k of the rectified other
    half (level pixels), i.e. other-half column u + k f (full-resolution px, local to the other half).

    Attributes:
        reference_grid: (H_r, W_l, 2) ``grid_sample`` coordinates (align_corners=False) on the level's
            reference image (padded to ceil(H / f) x ceil(W_ref / f) = H_l x W_l) of each rectified pixel.
        other_grid: (H_r, W_ol, 2) the same on the level's other image (H_l x W_ol).
        shifts: (D,) the integer shifts k (level px), ascending.
        index: (D, W_l) long: rectified other column u_c + k, clamped into the image (a ``gather`` index).
        valid: (D, H_r, W_l) bool: the rectified reference pixel and the shifted other sample are real
            (inside the halves, on other pixels that see through the prism) and k lies within the pixel's own
            searched range (sweep coordinates [-1, 1], half a level pixel of slack).
        back_grid: (H_l, W_l, 2) ``grid_sample`` coordinates on the rectified level (H_r x W_l) of every
            pixel of the (unrectified) level reference image.
        table: (K, H_r, W_l, 2) the exact sweep of each rectified reference pixel (:func:`tabulate_sweep` at
            its source position, full-sensor px): a shift becomes a sweep coordinate by
            :func:`~prismstereo.epipolar.sweep_table.column_to_sweep`.
        first_row: the rectified row (full-resolution px) of the level's top edge is first_row - 0.5.
    """

    reference_grid: torch.Tensor
    other_grid: torch.Tensor
    shifts: torch.Tensor
    index: torch.Tensor
    valid: torch.Tensor
    back_grid: torch.Tensor
    table: torch.Tensor
    first_row: float


class RowRectification(NamedTuple):
    """A fitted row rectification (float64).

    Attributes:
        reference: (n, n) A[i, j] of a(u, v) (row 0 unused: zero).
        other: (n, n) B[i, j] of b(X, Y).
        reference_width: W_ref.
        width: W, the full sensor width (the other half is columns W_ref..W-1).
        height: H.
        max_residual_px: largest |R_ref - R_oth(m)| over the fitting samples.
        rms_residual_px: its root mean square.
    """

    reference: torch.Tensor
    other: torch.Tensor
    reference_width: int
    width: int
    height: int
    max_residual_px: float
    rms_residual_px: float


def _norm(t: torch.Tensor, start: float, size: int) -> torch.Tensor:
    return 2.0 * (t - start + 0.5) / size - 1.0


def _design(sizes: tuple[int, int, int], u: torch.Tensor, v: torch.Tensor, side: str, n: int):
    """Basis rows (*, n * n) of a (reference) or b (other) at pixels (u, v)."""
    w_ref, w, h = sizes
    if side == "reference":
        tx = chebyshev_basis(_norm(u, 0.0, w_ref), n)
        tx = tx - chebyshev_basis(torch.zeros((), dtype=u.dtype, device=u.device), n)  # a = 0 at x(u) = 0
    else:
        tx = chebyshev_basis(_norm(u, w_ref, w - w_ref), n)
    ty = chebyshev_basis(_norm(v, 0.0, h), n)
    return (tx.unsqueeze(-1) * ty.unsqueeze(-2)).flatten(-2)


def fit_row_rectification(
    rig: BiPrismRig, fit: SweepFit, degree: int = 4, step: int | None = None, depths: int = 33
) -> RowRectification:
    """Fit the row warps of both halves to the exact sweep (see the module docstring).

    Args:
        rig: the rig.
        fit: :func:`~prismstereo.epipolar.sweep.fit_sweep` over the depth range to rectify for.
        degree: polynomial degree of a and b in each variable.
        step: reference pixel grid spacing (px) of the fitting samples; None: 8, halved while either axis of
            the reference half would get fewer than degree + 2 sample positions (with 4 x 6 positions on a
            64 x 48 sensor the degree-4 warp was underdetermined in (u, v): a solution with rows moved by
            ~1500 px fitted the samples to 2e-12 px).
        depths: number of sweep coordinates per pixel (uniform in s over [-1, 1]).

    Returns:
        RowRectification.

    Raises:
        OptionError: bad degree / step / depths. RigError: too few co-visible samples.

    Example:
        >>> from prismstereo.epipolar.sweep import fit_sweep
        >>> rig = thesis_setup1().downscaled(4)
        >>> rect = fit_row_rectification(rig, fit_sweep(rig, (300.0, 900.0)))
        >>> rect.max_residual_px < 0.01
        True
    """
    h, w_ref, w = rig.image_height, rig.reference_width, rig.image_width
    for name, value, low in (("degree", degree, 1), ("step", 1 if step is None else step, 1), ("depths", depths, 2)):
        if not isinstance(value, int) or value < low:
            raise OptionError(f"{name} must be an int >= {low}, got {value!r}")
    if step is None:
        step = 8
        while step > 1 and min(math.ceil(w_ref / step), math.ceil(h / step)) < degree + 2:
            step //= 2
    f64 = torch.float64
    uv = torch.stack(torch.meshgrid(torch.arange(0, w_ref, step, dtype=f64), torch.arange(0, h, step, dtype=f64),
                                    indexing="xy"), -1)  # (h', w', 2)
    coef = sweep_coefficients(fit, uv).permute(2, 0, 1, 3)
    pos = positions_at(coef, torch.linspace(-1.0, 1.0, depths, dtype=f64))  # (S, h', w', 2)
    rays = trace_pixels(rig, uv.reshape(-1, 2))
    seen = (rays.valid & rays.left).view(uv.shape[:2])
    x, y = pos[..., 0], pos[..., 1]
    ok = (x >= w_ref) & (x <= w - 1) & (y >= 0) & (y <= h - 1) & seen
    n = degree + 1
    if int(ok.sum()) < 4 * n * n:
        raise RigError(f"only {int(ok.sum())} co-visible samples to fit a degree-{degree} row rectification")
    u_s, v_s = uv[..., 0].expand_as(x)[ok], uv[..., 1].expand_as(x)[ok]
    sizes = (w_ref, w, h)
    design = torch.cat([_design(sizes, u_s, v_s, "reference", n), -_design(sizes, x[ok], y[ok], "other", n)], 1)
    keep = torch.ones(2 * n * n, dtype=torch.bool)
    keep[:n] = False  # A[0, :] multiplies T_0 - T_0(0) = 0
    rhs = y[ok] - v_s
    sol = torch.zeros(2 * n * n, dtype=f64)
    with torch_threads(1):  # LAPACK's threaded reductions round differently on other thread counts: one model, one fit
        sol[keep] = torch.linalg.lstsq(design[:, keep], rhs.unsqueeze(1), driver="gelsd").solution[:, 0]
    residual = design @ sol - rhs
    return RowRectification(sol[:n * n].view(n, n), sol[n * n:].view(n, n), w_ref, w, h,
                            float(residual.abs().max()), float(residual.pow(2).mean().sqrt()))


def rectified_rows(rect: RowRectification, uv: torch.Tensor, side: Side) -> torch.Tensor:
    """Rectified row R(u, v) of pixels of one half.

    Args:
        rect: the rectification.
        uv: (*, 2) full-sensor pixel coordinates (u, v) of the reference half, or of the other half.
        side: 'reference' or 'other'.

    Returns:
        (*,) rectified rows (full-resolution px), dtype of ``uv``.

    Example:
        >>> from prismstereo.epipolar.sweep import fit_sweep
        >>> rig = thesis_setup1().downscaled(4)
        >>> rect = fit_row_rectification(rig, fit_sweep(rig, (300.0, 900.0)))
        >>> r = rectified_rows(rect, torch.tensor([[63.5, 10.0]], dtype=torch.float64), "reference")
        >>> round(float(r), 6)  # the centre column keeps its rows
        10.0
    """
    check_option(side, SIDES, "side")
    coef = rect.reference if side == "reference" else rect.other
    n = coef.shape[0]
    basis = _design((rect.reference_width, rect.width, rect.height), uv[..., 0], uv[..., 1], side, n)
    return uv[..., 1] + basis @ coef.reshape(-1).to(uv)


def source_rows(rect: RowRectification, u: torch.Tensor, r: torch.Tensor, side: Side, iterations: int = 6
                ) -> torch.Tensor:
    """The inverse warp: the row v of column u whose rectified row is r (fixed-point iteration
    v <- r - a(u, v); the warps' vertical slope is far below 1).

    Args:
        rect: the rectification.
        u: (*) full-sensor columns.
        r: (*) rectified rows (broadcast with ``u``).
        side: 'reference' or 'other'.
        iterations: fixed-point steps.

    Returns:
        (*) rows v (px), dtype of ``u``.

    Example:
        >>> from prismstereo.epipolar.sweep import fit_sweep
        >>> rig = thesis_setup1().downscaled(4)
        >>> rect = fit_row_rectification(rig, fit_sweep(rig, (300.0, 900.0)))
        >>> u, r = torch.tensor([5.0], dtype=torch.float64), torch.tensor([40.0], dtype=torch.float64)
        >>> v = source_rows(rect, u, r, "reference")
        >>> round(float(rectified_rows(rect, torch.stack([u, v], -1), "reference")), 8)
        40.0
    """
    check_option(side, SIDES, "side")
    u, r = torch.broadcast_tensors(u, r.to(u))
    v = r.clone()
    for _ in range(iterations):
        v = r - (rectified_rows(rect, torch.stack([u, v], -1), side) - v)
    return v


def level_coverage(mask: torch.Tensor, factor: int) -> torch.Tensor:
    """Share of real pixels in each ``factor`` x ``factor`` block of a mask zero-padded to whole blocks: the
    validity of a pyramid level's box-downsampled pixels (a level pixel is real where this is ~1).

    Args:
        mask: (H, W) bool, e.g. the other half's pixels that see through the prism.
        factor: f >= 1.

    Returns:
        (ceil(H / f), ceil(W / f)) float64 in [0, 1].

    Example:
        >>> level_coverage(torch.tensor([[True, True, False]]), 2)
        tensor([[0.5000, 0.0000]], dtype=torch.float64)
    """
    h, w = mask.shape
    pad = (0, math.ceil(w / factor) * factor - w, 0, math.ceil(h / factor) * factor - h)
    return F.avg_pool2d(F.pad(mask.to(torch.float64)[None, None], pad), factor)[0, 0]


def rectified_level(
    rect: RowRectification, fit: SweepFit, factor: int, other_valid: torch.Tensor
) -> RectifiedLevel:
    """The sampling plan of a 1-D (shift) cost volume at pyramid level ``factor`` (see
    :class:`RectifiedLevel`).

    The rectified rows span every reference pixel's rectified row (the warps move rows by up to ~12 px, so
    the rectified images have a few more rows than the halves); the shifts span every pixel's searched range.

    Args:
        rect: from :func:`fit_row_rectification`.
        fit: the sweep fit of the searched depth range.
        factor: f >= 1, the level's box downsampling.
        other_valid: (H, W_o) bool, other-half pixels that see through the prism.

    Returns:
        RectifiedLevel (grids float64).

    Example:
        >>> from prismstereo.epipolar.sweep import fit_sweep
        >>> rig = thesis_setup1().downscaled(8); fit = fit_sweep(rig, (400.0, 900.0))
        >>> level = rectified_level(fit_row_rectification(rig, fit), fit, 2, torch.ones(96, 64, dtype=torch.bool))
        >>> level.valid.shape[1:], level.back_grid.shape
        (torch.Size([49, 32]), torch.Size([48, 32, 2]))
    """
    if not isinstance(factor, int) or factor < 1:
        raise OptionError(f"factor must be an int >= 1, got {factor!r}")
    f64 = torch.float64
    h, w_ref, w = rect.height, rect.reference_width, rect.width
    w_o = w - w_ref
    if tuple(other_valid.shape) != (h, w_o):
        raise OptionError(f"other_valid must be ({h}, {w_o}), got {tuple(other_valid.shape)}")
    f = factor
    h_l, w_l, w_ol = math.ceil(h / f), math.ceil(w_ref / f), math.ceil(w_o / f)
    raw = torch.stack(torch.meshgrid(torch.arange(w_ref, dtype=f64), torch.arange(h, dtype=f64), indexing="xy"), -1)
    rows = rectified_rows(rect, raw, "reference")
    first_row = math.floor(float(rows.min()))
    h_r = math.ceil((math.ceil(float(rows.max())) - first_row + 1) / f)
    r = first_row + (torch.arange(h_r, dtype=f64) + 0.5) * f - 0.5  # (H_r,) full-resolution rectified rows

    def level(t: torch.Tensor, size: int) -> torch.Tensor:  # full-resolution px -> normalised level coordinate
        return (t + 0.5) * 2.0 / (f * size) - 1.0

    u_c = torch.arange(w_l, dtype=f64)
    u = (u_c + 0.5) * f - 0.5
    v_src = source_rows(rect, u.view(1, -1), r.view(-1, 1), "reference")  # (H_r, W_l)
    ref_grid = torch.stack([level(u, w_l).expand_as(v_src), level(v_src, h_l)], -1)
    x_c = torch.arange(w_ol, dtype=f64)
    x = (x_c + 0.5) * f - 0.5
    y_src = source_rows(rect, (x + w_ref).view(1, -1), r.view(-1, 1), "other")  # (H_r, W_ol)
    other_grid = torch.stack([level(x, w_ol).expand_as(y_src), level(y_src, h_l)], -1)
    ref_ok = (v_src >= -0.5) & (v_src <= h - 0.5)
    mask = level_coverage(other_valid, f)[None, None]
    sampled = F.grid_sample(mask, other_grid.unsqueeze(0), mode="bilinear", padding_mode="zeros", align_corners=False)
    other_ok = (sampled[0, 0] > 0.999) & (y_src >= -0.5) & (y_src <= h - 0.5)  # (H_r, W_ol)

    # each rectified reference pixel's searched range of shifts (level px): its correspondences at s = -1 and 1
    src = torch.stack([u.expand_as(v_src), v_src.clamp(0, h - 1)], -1)
    table = tabulate_sweep(sweep_coefficients(fit, src).permute(2, 0, 1, 3))
    ends = table[[0, -1]]
    shift_ends = (ends[..., 0] - w_ref + 0.5) / f - 0.5 - u_c  # (2, H_r, W_l)
    lo, hi = shift_ends.amin(0) - 0.5, shift_ends.amax(0) + 0.5
    k_lo, k_hi = math.floor(float(lo[ref_ok].min())), math.ceil(float(hi[ref_ok].max()))
    shifts = torch.arange(k_lo, k_hi + 1, dtype=f64)
    columns = u_c.view(1, -1) + shifts.view(-1, 1)  # (D, W_l)
    index = columns.clamp(0, w_ol - 1).long()
    inside = (columns >= 0) & (columns <= w_ol - 1)
    k = shifts.view(-1, 1, 1)
    valid = (inside.unsqueeze(1) & other_ok[:, index].permute(1, 0, 2) & ref_ok & (k >= lo) & (k <= hi))

    level_px = (torch.arange(max(h_l, w_l), dtype=f64) + 0.5) * f - 0.5
    raw = torch.stack(torch.meshgrid(level_px[:w_l], level_px[:h_l], indexing="xy"), -1)  # (H_l, W_l, 2)
    rc = (rectified_rows(rect, raw, "reference") - first_row + 0.5) / f - 0.5
    back = torch.stack([level(raw[..., 0], w_l), (2.0 * rc + 1.0) / h_r - 1.0], -1)
    return RectifiedLevel(ref_grid, other_grid, shifts, index, valid, back, table, float(first_row))
