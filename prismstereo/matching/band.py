"""The fine band: every pixel re-estimated in a narrow band of hypotheses around an estimate, on the exact sweep.

After a coarse search (:mod:`prismstereo.matching.search`), a binned level's estimate or a previous frame's depth
has placed each reference pixel near its match, :class:`FineBand` searches 2 R + 1 hypotheses around it at full
resolution on the pixel's own sweep (the power series of :mod:`prismstereo.epipolar.series`): cost, box (blended
with a wider box in weak texture), winner, sub-pixel refinement. :func:`extend_estimate` carries a placement into
its invalid neighbours first, so that the band can still match pixels the coarser search lost at the edges of the
common field of view.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import nn

from prismstereo.conventions import to_grey
from prismstereo.epipolar.series import series_at, series_band
from prismstereo.errors import OptionError, ShapeError, check_number, check_shape
from prismstereo.matching.aggregate import box_filter
from prismstereo.matching.cost import Warped, reference_moments, sweep_cost
from prismstereo.matching.options import BandOptions
from prismstereo.matching.search import LevelResult, similarity
from prismstereo.matching.select import refine, winner_take_all
from prismstereo.matching.sweep_cost import sample_points
from prismstereo.runtime import tracing

__all__ = ["EXPORT_STRIP_VOXELS", "Extended", "FineBand", "STRIP_VOXELS", "extend_estimate", "texture_of"]

STRIP_VOXELS = 400_000
"""Fine band voxels per strip in torch eager (cache-sized float32 volumes): :attr:`FineBand.strip_voxels`."""
EXPORT_STRIP_VOXELS = 2_000_000
"""Voxels per strip of an exported graph (the pyramid's bands in one piece): :attr:`FineBand.export_strip_voxels`."""


class FineBand(nn.Module):
    """Full-resolution band of 2 R + 1 hypotheses (``step`` apart in s) around each pixel's estimate s0, on the
    exact sweep: cost, box, winner, sub-pixel refinement (no SGM: the coarse level already regularised).

    Where the reference window has little texture (grey standard deviation sigma over the cost window below
    ``weak_texture``) the box-averaged cost is blended with the cost averaged over ``wide_box``
    (when larger than the box): C = C_box + w (C_wide - C_box), w = max(0, 1 - sigma / weak_texture). A small
    window's minimum in weak texture or under defocus is mostly noise; a wider one keeps the sub-pixel fit
    stable there, and richly textured windows keep their small, sharp support.

    The band is centred on each pixel's own estimate, not rounded to the hypothesis grid: rounding made the
    parabola fits pixel-lock. A pixel whose best
    hypothesis is on the band's edge (its match lies beyond the band) is invalid with ``band_edges``
    'reject'; with 'clamp' its winner becomes the inner neighbour of that edge hypothesis, refined there (at
    most ``vertex_limit`` steps further out) and judged by that hypothesis' confidence (with R = 1 that is always the
    centre: taken by static slices, without a winner search or gathers). The band runs over horizontal
    strips whose cost and box filters see ``window // 2 + max(fine_box, wide_box) // 2`` rows beyond the strip,
    so the strips give the whole image's numbers (bitwise). Torch eager takes cache-sized strips; an exported graph
    takes larger bands in one piece and still larger ones in strips unrolled into the graph (the batch axis stays
    dynamic). The strip sizes are the attributes ``strip_voxels`` and ``export_strip_voxels`` (voxels per strip,
    at least 16 rows), :data:`STRIP_VOXELS` and :data:`EXPORT_STRIP_VOXELS` by default.

    Args:
        options: the band's cost ``fine_cost``, ``window``, ``census_threshold``, its box ``fine_box``,
            ``wide_box`` and ``weak_texture``, ``band_edges``, ``refinement`` (a resolved level's:
            :meth:`~prismstereo.classical.config.StereoConfig.band_options`).
        band: R.
        step: hypothesis spacing in s.
        split: the other half's first full-sensor column.
        with_match: return each pixel's match (False: ``match`` None, for a caller that moves s afterwards).
        vertex_limit: the sub-pixel fit's largest move from the winner, in steps (0.5: within half a step of a
            true minimum; 1.0: up to the band's outer sample, for a band placed on a prior that may lag the
            motion by a step, :class:`~prismstereo.classical.temporal.TemporalDepth`).

    Example:
        >>> from prismstereo.epipolar.sweep import fit_sweep, sweep_coefficients
        >>> from prismstereo.epipolar.series import sweep_series
        >>> from prismstereo.epipolar.sweep_table import tabulate_sweep, valid_interval
        >>> rig = thesis_setup1().downscaled(8); fit = fit_sweep(rig, (400.0, 900.0))
        >>> uv = torch.stack(torch.meshgrid(torch.arange(64.0), torch.arange(96.0), indexing="xy"), -1).double()
        >>> coefficients = sweep_coefficients(fit, uv).permute(2, 0, 1, 3)
        >>> series = sweep_series(coefficients).float()
        >>> interval = valid_interval(tabulate_sweep(coefficients).float(), torch.ones(96, 64, dtype=torch.bool), 64)
        >>> from prismstereo.matching.options import AggregationConfig, CostConfig
        >>> fine = FineBand(BandOptions(CostConfig(), AggregationConfig(), "clamp", "parabola"), 2, 0.05, 64)
        >>> res = fine(torch.rand(1, 1, 96, 64), torch.rand(1, 1, 96, 64), torch.zeros(1, 1, 96, 64),
        ...            torch.ones(1, 1, 96, 64, dtype=torch.bool), series, interval)
        >>> res.s.shape
        torch.Size([1, 1, 96, 64])
    """

    def __init__(self, options: BandOptions, band: int, step: float, split: int, with_match: bool = True, *,
                 vertex_limit: float = 0.5) -> None:
        super().__init__()
        check_number(vertex_limit, "vertex_limit", 0.0, 1.0, open_low=True)
        self.options, self.band, self.step, self.split = options.checked(), band, step, split
        self.with_match, self.vertex_limit = with_match, float(vertex_limit)
        cost, aggregation = options.cost, options.aggregation
        self.cost, self.window, self.census_threshold = cost.fine_cost, cost.window, float(cost.census_threshold)
        self.box, self.wide_box, self.weak_texture = aggregation.fine_box, aggregation.wide_box, float(
            aggregation.weak_texture)
        self.band_edges, self.refinement = options.band_edges, options.refinement
        self.strip_voxels, self.export_strip_voxels = STRIP_VOXELS, EXPORT_STRIP_VOXELS

    def forward(self, reference: torch.Tensor, other: torch.Tensor, s0: torch.Tensor, ok0: torch.Tensor,
                series: torch.Tensor, interval: torch.Tensor,
                moments: tuple[torch.Tensor, torch.Tensor] | None = None) -> LevelResult:
        """The band around ``s0`` (B, 1, H, W) (detached, in [-1, 1]) with the estimate's validity ``ok0``;
        ``series`` (2, D + 1, H, W) the exact sweep (:func:`~prismstereo.epipolar.series.sweep_series`),
        ``interval`` (2, H, W) each pixel's valid s (:func:`~prismstereo.epipolar.sweep_table.valid_interval`);
        ``moments`` optionally the reference's :func:`~prismstereo.matching.cost.reference_moments` over the cost
        window, (B, 1, H, W) each (ZNCC's, and the wide box's weight from the variance's root; computed here when
        None)."""
        exporting = tracing()
        h = reference.shape[-2]
        halo = self.window // 2 + max(self.box, self.wide_box) // 2
        # per image when exporting: the graph's batch axis is dynamic, and a traced batch size in this
        # arithmetic made the strips' slices depend on it (a batch of 4 failed in onnxruntime)
        voxels = (2 * self.band + 1) * int(reference.shape[-1]) * (1 if exporting else int(reference.shape[0]))
        rows = max(16, (self.export_strip_voxels if exporting else self.strip_voxels) // voxels)
        if rows >= h:  # one piece: no slices (in an exported graph each Slice, and a Concat of one, is a copy)
            return self._rows(reference, other, s0, ok0, series, 0, interval, moments)
        strips = []
        for top in range(0, h, rows):
            lo, hi = max(0, top - halo), min(h, top + rows + halo)
            res = self._rows(reference[..., lo:hi, :], other, s0[..., lo:hi, :], ok0[..., lo:hi, :],
                             series, lo, interval[:, lo:hi],
                             None if moments is None else tuple(m[..., lo:hi, :] for m in moments))
            keep = slice(top - lo, top - lo + min(rows, h - top))
            strips.append([None if t is None else t[..., keep, :] for t in res])
        return LevelResult(*(None if ts[0] is None else torch.cat(ts, -2) for ts in zip(*strips, strict=True)))

    def _rows(self, reference: torch.Tensor, other: torch.Tensor, s0: torch.Tensor, ok0: torch.Tensor,
              series: torch.Tensor, top: int, interval: torch.Tensor,
              moments: tuple[torch.Tensor, torch.Tensor] | None = None) -> LevelResult:
        """The band on rows ``top`` ... of the image (``series`` whole, ``interval`` of these rows)."""
        step = self.step
        offsets = torch.arange(-self.band, self.band + 1, device=reference.device).to(reference.dtype) * step
        # the band's positions s0 + t_j from each pixel's Taylor coefficients at s0 (exported as one MatMul: in
        # onnxruntime cheaper than Horner's rule over the (B, J, H, W) coordinates), in other-half pixels
        x, y = series_band(series, s0, offsets, top, origin=(self.split, 0.0))
        channels = reference.shape[1]
        if self.cost == "zncc":  # ZNCC compares grey windows: sample the grey image (linear)
            reference, other = to_grey(reference, dim=1), to_grey(other, dim=1)
        lo, hi = interval.to(reference).unbind(0)
        t = offsets.view(1, -1, 1, 1)  # s0 + t_j within the pixel's interval (beyond [-1, 1]: outside it)
        warped = Warped(sample_points(other, x, y), (t >= lo - s0) & (t <= hi - s0))
        wide = self.wide_box > self.box
        if moments is None and (wide or self.cost == "zncc"):
            moments = reference_moments(reference, self.window)
        volume = sweep_cost(reference, warped, self.cost, self.window, self.census_threshold,
                            moments if self.cost == "zncc" else None)
        local = box_filter(volume, self.box)
        if wide:  # weak texture: the cost averaged over a wider box (see FineBand)
            texture = texture_of(moments[1]).detach()
            weight = (1.0 - texture / self.weak_texture).clamp(0.0, 1.0)  # a weight, not a gradient path
            local = local + weight * (box_filter(volume, self.wide_box) - local)
        if self.band_edges == "clamp" and self.band == 1:  # the winner is always the centre: static slices
            j: torch.Tensor | int = 1
        else:
            j, _ = winner_take_all(local.detach())
            if self.band_edges == "clamp":  # a winner on the band's edge: refined from its inner neighbour instead
                j = j.clamp(1, 2 * self.band - 1)
        refined = refine(local, local, j, self.refinement, self.cost, self.vertex_limit)
        if isinstance(j, int):
            frac, s_j, ok = refined - j, s0 + offsets[j], ok0 & warped.valid[:, j:j + 1]
        else:  # the winner's s and validity by arithmetic on (B, 1, H, W): the numbers of gathers from the band
            frac = refined - j.to(reference.dtype)
            s_j = s0 + (j - self.band).to(reference.dtype) * step
            ok = ok0 & (s_j >= lo) & (s_j <= hi) & (j > 0) & (j < 2 * self.band)
        s = s_j + frac * step
        # the match: the series at s (16 multiply-adds per pixel with setup 1's degree 4, cheaper in onnxruntime
        # than gathering the band's samples around s and interpolating between them, which was within 2e-4 px)
        match = torch.cat(series_at(series, s, top), 1) if self.with_match else None
        return LevelResult(s, ok, similarity(_pick(local, j), self.cost, channels, self.window), match)


def texture_of(variance: torch.Tensor) -> torch.Tensor:
    """The reference's texture, the grey standard deviation over the cost window, from the variance of its
    :func:`~prismstereo.matching.cost.reference_moments` (floored at 1e-12 before the root: a flat window's texture
    is 1e-6 and its gradient 0, not infinite): the wide box's weight and a feature of the calibrated confidence.

    Example:
        >>> texture_of(torch.tensor([0.04, 0.0])).tolist()
        [0.20000000298023224, 9.999999974752427e-07]
    """
    return variance.clamp_min(1e-12).sqrt()


def _pick(t: torch.Tensor, j: torch.Tensor | int) -> torch.Tensor:
    """(B, 1, H, W) entries of (B, J, H, W) ``t`` at each pixel's hypothesis ``j`` ((B, 1, H, W) long), or at one
    hypothesis for all (an int: a static slice, no gather in an exported graph)."""
    return t[:, j:j + 1] if isinstance(j, int) else t.gather(1, j)


class Extended(NamedTuple):
    """:func:`extend_estimate`'s result, (B, 1, H, W) each.

    Attributes:
        s: the estimate, extended to invalid pixels in reach of valid ones.
        reach: bool, where it is defined (valid, or a valid pixel within the radius).
    """

    s: torch.Tensor
    reach: torch.Tensor


def extend_estimate(s: torch.Tensor, valid: torch.Tensor, radius: int) -> Extended:
    """Give invalid pixels within ``radius`` pixels of a valid one the mean s of the valid pixels of their
    (2 radius + 1)^2 window; valid pixels, and those out of reach, keep theirs.

    A coarse level loses a margin of about its window at the edges of the common field of view (its windows
    leave the other half's image there) and elsewhere along invalid patches; the fine band, with its own
    smaller full-resolution windows and checks, can still match most of these pixels if it is placed near
    the right s. (:class:`~prismstereo.classical.model.PrismStereo` accepts such a pixel only at a higher confidence.)

    Args:
        s: (B, 1, H, W) estimate; any value where invalid (NaN too: kept only where out of reach).
        valid: (B, 1, H, W) bool.
        radius: >= 0 pixels (0: unchanged).

    Example:
        >>> s = torch.tensor([[[[0.2, 0.4, 9.0, 9.0]]]]); ok = torch.tensor([[[[True, True, False, False]]]])
        >>> t, reach = extend_estimate(s, ok, 1)
        >>> [round(v, 3) for v in t[0, 0, 0].tolist()], reach[0, 0, 0].tolist()
        ([0.2, 0.4, 0.4, 9.0], [True, True, True, False])
    """
    check_shape(s, ["B", 1, "H", "W"], "s")
    if valid.shape != s.shape or valid.dtype != torch.bool:
        raise ShapeError(f"valid must be a bool tensor of s's shape {tuple(s.shape)}, got {valid.dtype} "
                         f"{tuple(valid.shape)}")
    if not isinstance(radius, int) or radius < 0:
        raise OptionError(f"radius must be an int >= 0, got {radius!r}")
    if radius == 0:
        return Extended(s, valid)
    # the window's sum of valid estimates and its count of valid pixels, as means over the same pixels: the ratio is
    # the valid pixels' mean
    total, share = box_filter(torch.cat([torch.where(valid, s, s.new_tensor(0.0)), valid.to(s.dtype)], 1),
                              2 * radius + 1).split(1, 1)
    mean = total / share.clamp_min(torch.finfo(s.dtype).tiny)
    reach = valid | (share > 0)
    return Extended(torch.where(valid | ~reach, s, mean), reach)
