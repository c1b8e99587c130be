"""Building a rig's search level: the coarse (or single) level of :class:`~prismstereo.model.PrismStereo`, from
the rig's exact sweep, as one of the swappable searches of :mod:`prismstereo.matching.levels`."""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import nn

from prismstereo.epipolar.row_rectify import fit_row_rectification, level_coverage, rectified_level
from prismstereo.epipolar.sweep import SweepFit, positions_at, sweep_coefficients, sweep_hypotheses
from prismstereo.errors import check_option
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.matching.levels import RectifiedSearch, SearchOptions, SweepSearch
from prismstereo.matching.sweep_cost import warp_slices

__all__ = ["BuiltSearch", "build_search"]


class BuiltSearch(NamedTuple):
    """A rig's coarse (or single) level search (:func:`build_search`).

    Attributes:
        search: :class:`RectifiedSearch` or :class:`SweepSearch`.
        rectification_residual_px: the row rectification's largest residual (px) for 'rectified', else None.
    """

    search: nn.Module
    rectification_residual_px: float | None


def build_search(rig: BiPrismRig, fit: SweepFit, fine: torch.Tensor, options: SearchOptions, sampling: str,
                 factor: int, num_hypotheses: int, other_valid: torch.Tensor,
                 lr_threshold: float | None = None) -> BuiltSearch:
    """The search over a rig's whole range at its coarse level (or, with ``factor`` 1, its single level).

    'rectified': a 1-D shift volume on halves row-rectified for this rig and sweep
    (:func:`~prismstereo.epipolar.row_rectify.fit_row_rectification`). 'sweep': the exact per-pixel sweep, at full
    resolution with ``num_hypotheses`` (``fine``, the polynomials of every reference pixel) or, with ``factor`` f
    > 1, at the f x f box-downsampled level with hypotheses <= 1 level pixel apart and each sample's validity fixed
    in advance (the level's grid is).

    Args:
        rig: the rig (full resolution of the level's input).
        fit: its sweep fit (:func:`~prismstereo.epipolar.sweep.fit_sweep`).
        fine: (N, H, W_ref, 2) sweep polynomials of every reference pixel, full-sensor pixels.
        options: matching options of the level.
        sampling: 'rectified' or 'sweep'.
        factor: the level's downsampling f.
        num_hypotheses: D of a single full-resolution level.
        other_valid: (H, W_o) bool, the other half's pixels that see through the prism.
        lr_threshold: left-right check of the rectified level (level pixels), None to skip it.

    Returns:
        BuiltSearch.

    Raises:
        OptionError: unknown sampling.

    Example:
        >>> from prismstereo.epipolar.sweep import fit_sweep
        >>> rig = thesis_setup1().downscaled(8); fit = fit_sweep(rig, (400.0, 700.0))
        >>> uv = torch.stack(torch.meshgrid(torch.arange(64.0), torch.arange(96.0), indexing="xy"), -1).double()
        >>> fine = sweep_coefficients(fit, uv).permute(2, 0, 1, 3)
        >>> built = build_search(rig, fit, fine, SearchOptions(), "sweep", 1, 15, torch.ones(96, 64, dtype=torch.bool))
        >>> built.search.num_hypotheses, built.rectification_residual_px
        (15, None)
    """
    check_option(sampling, ("rectified", "sweep"), "sampling")
    h, w_ref, f64 = rig.image_height, rig.reference_width, torch.float64
    if sampling == "rectified":  # a 1-D shift volume on row-rectified halves
        rect = fit_row_rectification(rig, fit)
        level = rectified_level(rect, fit, factor, other_valid)
        return BuiltSearch(RectifiedSearch(options, level, factor, w_ref, lr_threshold), rect.max_residual_px)
    if factor == 1:
        return BuiltSearch(SweepSearch(options, _normalised(rig, fine, 1).float(), num_hypotheses,
                                       other_valid=other_valid), None)
    hc, wc = math.ceil(h / factor), math.ceil(w_ref / factor)
    uvc = (torch.stack(torch.meshgrid(torch.arange(wc, dtype=f64), torch.arange(hc, dtype=f64),
                                      indexing="xy"), -1) + 0.5) * factor - 0.5
    coarse = sweep_coefficients(fit, uvc).permute(2, 0, 1, 3)
    valid_c = level_coverage(other_valid, factor) > 0.999
    # the coarse grid is fixed, so is the validity of its samples: (D_c, H_c, W_c) bool
    num_c = sweep_hypotheses(coarse / factor)
    probe = torch.zeros(1, 1, valid_c.shape[0], valid_c.shape[1], dtype=f64)
    coarse = _normalised(rig, coarse, factor)  # grid_sample units of the coarse other image
    grid_c = positions_at(coarse, torch.linspace(-1.0, 1.0, num_c, dtype=f64))
    valid = warp_slices(probe, grid_c.unsqueeze(0), valid_c).valid[0]
    return BuiltSearch(SweepSearch(options, coarse.float(), num_c, valid=valid), None)


def _normalised(rig: BiPrismRig, coefficients: torch.Tensor, factor: int) -> torch.Tensor:
    """Map pixel-unit polynomials of full-sensor positions to grid_sample coordinates (align_corners=False) of the
    other half, padded to a multiple of ``factor`` (the coarse level's box downsampling): the map is affine, so
    only T_0's coefficient gets the offset."""
    split, h, w_o = rig.reference_width, rig.image_height, rig.image_width - rig.reference_width
    width, height = math.ceil(w_o / factor) * factor, math.ceil(h / factor) * factor
    scale = coefficients.new_tensor([2.0 / width, 2.0 / height])
    offset = coefficients.new_tensor([(1.0 - 2.0 * split) / width - 1.0, 1.0 / height - 1.0])
    return torch.cat([coefficients[:1] * scale + offset, coefficients[1:] * scale])
