"""Building a rig's search level: the coarse (or single) level of :class:`~prismstereo.model.PrismStereo`, from
the rig's exact sweep, as one of the swappable searches of :mod:`prismstereo.matching.levels`."""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import nn

from prismstereo.epipolar.row_rectify import fit_row_rectification, level_coverage, rectified_level
from prismstereo.epipolar.sweep import SweepFit, sweep_coefficients, sweep_hypotheses
from prismstereo.errors import check_option
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.matching.levels import RectifiedSearch, SearchOptions, SweepSearch
from prismstereo.matching.sweep_sampler import block_centres, sweep_sampler

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
    h, w_ref = rig.image_height, rig.reference_width
    if sampling == "rectified":  # a 1-D shift volume on row-rectified halves
        rect = fit_row_rectification(rig, fit)
        level = rectified_level(rect, fit, factor, other_valid)
        return BuiltSearch(RectifiedSearch(options, level, factor, w_ref, lr_threshold), rect.max_residual_px)
    if factor == 1:
        sampler = sweep_sampler(fit, num_hypotheses, other_start=w_ref, other_valid=other_valid, precompute=False,
                                dtype=torch.float32, coefficients=fine)
        return BuiltSearch(SweepSearch(options, sampler), None)
    # the coarse grid is fixed, so is the validity of its samples: (D_c, H_c, W_c) bool
    coarse = sweep_coefficients(fit, block_centres(math.ceil(h / factor), math.ceil(w_ref / factor), factor,
                                                   fit.coefficients)).permute(2, 0, 1, 3)
    sampler = sweep_sampler(fit, sweep_hypotheses(coarse / factor), factor=factor, other_start=w_ref,
                            other_valid=level_coverage(other_valid, factor) > 0.999, dtype=torch.float32,
                            coefficients=coarse)
    return BuiltSearch(SweepSearch(options, sampler), None)
