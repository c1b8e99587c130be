"""Sampling grids for plane-sweep matching: exact per-hypothesis grids and a fast shift-band form.

Depth hypotheses z_1..z_D (uniform in inverse depth by default). For every reference pixel (v, u) of the
left half (u < apex column, W_ref columns) and every hypothesis, the *exact grid* holds the right-half
pixel that sees the reference pixel's point at depth z_i: trace the reference ray, take its point at
Z = z_i, project it through the right face (:func:`~prismstereo.geometry.projection.project_points`).

Per-hypothesis ``grid_sample`` is the slowest way to build a cost volume, so :func:`shift_bands` gives a
fast form: the hypotheses are split into bands; for each band the right half is resampled *once* into a
row-aligned image in which every hypothesis of the band is a pure (fractional) horizontal shift of the
reference half. Band b's warp maps warped column x of row v to the exact right-half position of
reference pixel u' = x + p0_b - 0 at the band's centre depth; hypothesis i then reads column
x = u + shift_i - p0_b. :func:`band_residual` measures the difference to the exact grid (px).

Grid conventions: ``uv`` are full-sensor pixel coordinates; ``normalised`` grids address the *right half
crop* (columns W_ref..W-1 of the image, as :func:`torch.nn.functional.grid_sample` input) with
``align_corners=False``: x = (2 (u - W_ref) + 1) / (W - W_ref) - 1, y = (2 v + 1) / H - 1.
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

import torch

from prismstereo.errors import OptionError, RigError, check_option, check_shape
from prismstereo.geometry.optics import points_at_depth, trace_pixels
from prismstereo.geometry.parameters import RigParameters
from prismstereo.geometry.projection import project_points
from prismstereo.geometry.rig import BiPrismRig

__all__ = [
    "SamplingGrid",
    "ShiftBands",
    "BandResidual",
    "depth_hypotheses",
    "normalise_right_grid",
    "exact_sampling_grid",
    "shift_bands",
    "band_residual",
    "bands_for_tolerance",
]

Spacing = Literal["inverse", "linear"]


class SamplingGrid(NamedTuple):
    """Exact right-half positions of reference pixels at each depth hypothesis.

    Attributes:
        uv: (D, H, W_ref, 2) full-sensor pixel coordinates in the right half.
        valid: (D, H, W_ref) bool: the correspondence exists (on the sensor, through the right face).
        normalised: (D, H, W_ref, 2) ``uv`` for ``grid_sample`` on the right-half crop (align_corners=False).
        depths: (D,) the hypotheses (mm).
    """

    uv: torch.Tensor
    valid: torch.Tensor
    normalised: torch.Tensor
    depths: torch.Tensor


class ShiftBands(NamedTuple):
    """The fast form: one warp per band, and a fractional shift per hypothesis.

    Attributes:
        maps: (B, H, W_x, 2) full-sensor right-half positions sampled by band b's warped image column x.
        normalised: (B, H, W_x, 2) ``maps`` for ``grid_sample`` on the right-half crop.
        origin: (B,) p0_b: warped column x of band b stands for shifted position p = x + p0_b.
        shifts: (D,) hypothesis i compares reference column u with shifted position u + shifts[i].
        band_of: (D,) band index of each hypothesis.
        depths: (D,) the hypotheses (mm).
    """

    maps: torch.Tensor
    normalised: torch.Tensor
    origin: torch.Tensor
    shifts: torch.Tensor
    band_of: torch.Tensor
    depths: torch.Tensor


class BandResidual(NamedTuple):
    """Difference (px) between the fast form's sampling positions and the exact grid.

    Attributes:
        max_px: largest Euclidean difference over valid samples.
        max_horizontal_px, max_vertical_px: largest |du| and |dv|.
        mean_px: mean Euclidean difference.
    """

    max_px: float
    max_horizontal_px: float
    max_vertical_px: float
    mean_px: float


def depth_hypotheses(
    z_min: float, z_max: float, num: int, spacing: Spacing = "inverse", dtype: torch.dtype = torch.float64
) -> torch.Tensor:
    """D depth hypotheses from z_min to z_max (mm), uniform in inverse depth (default) or in depth.

    Uniform inverse depth makes neighbouring hypotheses roughly equally far apart in the image (disparity
    is close to linear in 1/Z).

    Example:
        >>> depth_hypotheses(250.0, 1000.0, 4)
        tensor([ 250.0000,  333.3333,  500.0000, 1000.0000], dtype=torch.float64)
    """
    check_option(spacing, ("inverse", "linear"), "spacing")
    if not (0 < z_min < z_max) or not isinstance(num, int) or num < 2:
        raise RigError(f"need 0 < z_min < z_max and num >= 2, got {z_min}, {z_max}, {num}")
    if spacing == "inverse":
        return 1.0 / torch.linspace(1.0 / z_min, 1.0 / z_max, num, dtype=dtype)
    return torch.linspace(z_min, z_max, num, dtype=dtype)


def normalise_right_grid(uv: torch.Tensor, rig: BiPrismRig | RigParameters) -> torch.Tensor:
    """Full-sensor right-half pixels (*, 2) -> ``grid_sample`` coordinates on the right-half crop
    (align_corners=False; see the module docstring).

    Example:
        >>> normalise_right_grid(torch.tensor([512.0, 383.5]), thesis_setup1())
        tensor([-0.9980,  0.0000])
    """
    w, h = _size(rig)
    w_ref = rig.reference_width
    x = (2.0 * (uv[..., 0] - w_ref) + 1.0) / (w - w_ref) - 1.0
    y = (2.0 * uv[..., 1] + 1.0) / h - 1.0
    return torch.stack([x, y], dim=-1)


def _size(rig: BiPrismRig | RigParameters) -> tuple[int, int]:
    if isinstance(rig, BiPrismRig):
        return rig.image_width, rig.image_height
    return rig.width, rig.height


def _reference_pixels(rig, like: torch.Tensor, rows: torch.Tensor | None, columns: torch.Tensor) -> torch.Tensor:
    h = _size(rig)[1]
    v = torch.arange(h, dtype=like.dtype) if rows is None else rows.to(like)
    vv, uu = torch.meshgrid(v, columns.to(like), indexing="ij")
    return torch.stack([uu, vv], dim=-1)  # (H, W, 2)


def _positions(
    rig: BiPrismRig | RigParameters, uv_ref: torch.Tensor, depths: torch.Tensor, extend: bool
) -> tuple[torch.Tensor, torch.Tensor]:
    """Exact right positions (D, *, 2) and validity for reference pixels (*, 2), warm-started over depth."""
    rays = trace_pixels(rig, uv_ref, half="left" if extend else "auto")
    ok_ray = rays.valid & (rays.left | extend)
    out, valid, prev = [], [], None
    for z in depths:
        pts = points_at_depth(rays, z)
        proj = project_points(rig, pts, "right") if prev is None else project_points(
            rig, pts, "right", iterations=3, initial_uv=prev)
        # warm start from converged neighbours only (NaN: start from the virtual pinhole)
        prev = torch.where(proj.valid.unsqueeze(-1), proj.uv.detach(), torch.full_like(proj.uv, float("nan")))
        out.append(proj.uv)
        valid.append(proj.valid & ok_ray)
    return torch.stack(out), torch.stack(valid)


def exact_sampling_grid(
    rig: BiPrismRig | RigParameters, depths: torch.Tensor, rows: torch.Tensor | None = None
) -> SamplingGrid:
    """The exact plane-sweep grid (D, H, W_ref, 2) for the given depth hypotheses.

    Each depth is solved from the previous depth's solution where that converged (three Newton steps plus
    the implicit step), which reproduces the exact correspondence to ~1e-12 px in float64.
    Differentiable w.r.t. depths and rig parameters (pass :class:`RigParameters` requiring grad).

    Args:
        rig: the rig.
        depths: (D,) hypotheses (mm), e.g. :func:`depth_hypotheses`; dtype sets the computation's dtype.
        rows: optional (H',) subset of image rows (default all rows).

    Returns:
        SamplingGrid.

    Example:
        >>> small = thesis_setup1().downscaled(8)
        >>> exact_sampling_grid(small, depth_hypotheses(300.0, 1200.0, 8)).uv.shape
        torch.Size([8, 96, 64, 2])
    """
    check_shape(depths, ["D"], "depths")
    w_ref = rig.reference_width
    uv_ref = _reference_pixels(rig, depths, rows, torch.arange(w_ref, dtype=depths.dtype))
    uv, valid = _positions(rig, uv_ref, depths, extend=False)
    return SamplingGrid(uv, valid, normalise_right_grid(uv, rig), depths)


def _bands(num: int, bands: int) -> list[torch.Tensor]:
    return [chunk for chunk in torch.arange(num).tensor_split(bands) if chunk.numel()]


def shift_bands(
    rig: BiPrismRig | RigParameters,
    depths: torch.Tensor,
    bands: int,
    rows: torch.Tensor | None = None,
    exact: SamplingGrid | None = None,
) -> ShiftBands:
    """Build the fast shift-band form for ``bands`` contiguous bands of the hypotheses.

    Band b's warp (centre hypothesis c): warped column x of row v holds the exact right position of the
    (possibly fractional, possibly beyond the apex, traced through the extended left face) reference column
    u' = x + p0_b - shift_c at depth z_c. A hypothesis i of the band gets the shift
    shift_i = shift_c + mean over pixels of (U(u, z_i) - U(u, z_c)) / (dU/du), the reference-column offset
    that best matches the exact horizontal position (shift_c = 0 by convention).

    Args:
        rig: the rig.
        depths: (D,) hypotheses (mm).
        bands: number of bands, 1 <= bands <= D.
        rows: optional subset of rows.
        exact: the exact grid for the same depths and rows, if already computed (saves its cost).

    Returns:
        ShiftBands.

    Example:
        >>> small = thesis_setup1().downscaled(8)
        >>> sb = shift_bands(small, depth_hypotheses(300.0, 1200.0, 16), bands=2)
        >>> sb.maps.shape[0], sb.shifts.shape
        (2, torch.Size([16]))
    """
    check_shape(depths, ["D"], "depths")
    if not isinstance(bands, int) or not 1 <= bands <= depths.shape[0]:
        raise OptionError(f"bands must be an int in [1, D={depths.shape[0]}], got {bands!r}")
    w_ref = rig.reference_width
    dt = depths.dtype
    if exact is None:
        exact = exact_sampling_grid(rig, depths, rows)
    exact, valid = exact.uv, exact.valid  # (D, H, W_ref, 2)
    shifts = torch.zeros(depths.shape[0], dtype=dt)
    band_of = torch.zeros(depths.shape[0], dtype=torch.long)
    layout = []
    for b, idx in enumerate(_bands(depths.shape[0], bands)):
        c = int(idx[len(idx) // 2])
        du_dx = torch.gradient(exact[c, ..., 0], dim=-1)[0]  # dU/du at the centre depth
        for i in idx.tolist():
            m = valid[i] & valid[c]
            delta = (exact[i, ..., 0] - exact[c, ..., 0]) / du_dx
            shifts[i] = delta[m].mean() if m.any() else 0.0
        band_of[idx] = b
        lo, hi = float(shifts[idx].min()), float(shifts[idx].max())
        p0 = math.floor(lo) - 1
        layout.append((c, p0, w_ref + math.ceil(hi) + 2 - p0))
    width = max(wx for _, _, wx in layout)
    maps, origin = [], []
    for c, p0, _ in layout:
        xs = torch.arange(width, dtype=dt) + p0  # shifted positions p; reference column u' = p - shift_c
        uv_w = _reference_pixels(rig, depths, rows, xs - shifts[c])
        pos, _ = _positions(rig, uv_w, depths[c:c + 1], extend=True)
        maps.append(pos[0])
        origin.append(p0)
    maps_t = torch.stack(maps)
    return ShiftBands(maps_t, normalise_right_grid(maps_t, rig), torch.tensor(origin), shifts, band_of, depths)


def _band_positions(sb: ShiftBands, w_ref: int) -> torch.Tensor:
    """(D, H, W_ref, 2) positions the fast form samples: maps linearly interpolated at x = u + shift - p0."""
    out = []
    u = torch.arange(w_ref, dtype=sb.maps.dtype)
    for i in range(sb.shifts.shape[0]):
        b = int(sb.band_of[i])
        x = u + sb.shifts[i] - sb.origin[b]
        x0 = torch.floor(x).long().clamp(0, sb.maps.shape[2] - 2)
        a = (x - x0).view(1, -1, 1)
        m = sb.maps[b]
        out.append((1 - a) * m[:, x0] + a * m[:, x0 + 1])
    return torch.stack(out)


def band_residual(exact: SamplingGrid, bands: ShiftBands) -> BandResidual:
    """Compare the fast form with the exact grid on every valid sample (same rig, depths, rows).

    Example:
        >>> small = thesis_setup1().downscaled(8)
        >>> d = depth_hypotheses(300.0, 1200.0, 16)
        >>> res = band_residual(exact_sampling_grid(small, d), shift_bands(small, d, 4))
        >>> res.max_px < 0.1 and res.mean_px < 0.01
        True
    """
    if exact.uv.shape[0] != bands.shifts.shape[0]:
        raise RigError("exact grid and shift bands must use the same hypotheses")
    fast = _band_positions(bands, exact.uv.shape[2])
    diff = (fast - exact.uv)[exact.valid]
    if diff.numel() == 0:
        raise RigError("no valid sample to compare")
    return BandResidual(
        max_px=float(diff.norm(dim=-1).max()), max_horizontal_px=float(diff[:, 0].abs().max()),
        max_vertical_px=float(diff[:, 1].abs().max()), mean_px=float(diff.norm(dim=-1).mean()),
    )


def bands_for_tolerance(
    rig: BiPrismRig | RigParameters,
    depths: torch.Tensor,
    tolerance_px: float = 0.05,
    max_bands: int | None = None,
    rows: torch.Tensor | None = None,
) -> tuple[ShiftBands, BandResidual]:
    """The fewest bands (doubling from 1) whose residual against the exact grid is below ``tolerance_px``.

    Raises:
        RigError: if even one band per hypothesis misses the tolerance.

    Example:
        >>> small = thesis_setup1().downscaled(8)
        >>> sb, res = bands_for_tolerance(small, depth_hypotheses(300.0, 1200.0, 16))
        >>> res.max_px < 0.05 and res.mean_px < 0.01  # the default tolerance holds by construction
        True
    """
    exact = exact_sampling_grid(rig, depths, rows)
    limit = max_bands or depths.shape[0]
    bands = 1
    while True:
        sb = shift_bands(rig, depths, min(bands, limit), rows, exact)
        res = band_residual(exact, sb)
        if res.max_px < tolerance_px:
            return sb, res
        if bands >= limit:
            raise RigError(f"no band count up to {limit} reaches {tolerance_px} px (best {res.max_px:.3f} px)")
        bands *= 2
