"""A classical level's whole-range search, built from its resolved options.

:mod:`prismstereo.matching.search` holds the two searches with one interface (the row-rectified shift volume and
the exact per-pixel sweep) and their one decision; :func:`build_search` picks and builds one for a level of the
classical chain from its options (``sampling``, ``coarse_factor``, ``num_hypotheses``, the matching options):
the rig's row rectification, or its sweep sampled at the level's coarse grid.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import nn

from prismstereo.classical.config import StereoConfig
from prismstereo.epipolar.row_rectify import fit_row_rectification, level_coverage, rectified_level
from prismstereo.epipolar.sweep import SweepFit, sweep_coefficients, sweep_hypotheses
from prismstereo.errors import check_option
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.matching.search import RectifiedSearch, SweepSearch
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


def build_search(rig: BiPrismRig, fit: SweepFit, fine: torch.Tensor, config: StereoConfig,
                 other_valid: torch.Tensor) -> BuiltSearch:
    """The search over a rig's whole range at its coarse level (or, with ``coarse_factor`` 1, its single level).

    'rectified': a 1-D shift volume on halves row-rectified for this rig and sweep
    (:func:`~prismstereo.epipolar.row_rectify.fit_row_rectification`). 'sweep': the exact per-pixel sweep, at full
    resolution with ``num_hypotheses`` (``fine``, the polynomials of every reference pixel) or, with
    ``coarse_factor`` f > 1, at the f x f box-downsampled level with hypotheses <= 1 level pixel apart and each
    sample's validity fixed in advance (the level's grid is).

    Args:
        rig: the rig (full resolution of the level's input).
        fit: its sweep fit (:func:`~prismstereo.epipolar.sweep.fit_sweep`).
        fine: (N, H, W_ref, 2) sweep polynomials of every reference pixel, full-sensor pixels.
        config: the level's resolved options (:func:`~prismstereo.classical.defaults.resolve_level`): ``sampling``,
            ``coarse_factor`` f, ``num_hypotheses`` (D of a single full-resolution level), the matching options.
        other_valid: (H, W_o) bool, the other half's pixels that see through the prism.

    Returns:
        BuiltSearch.

    Raises:
        OptionError: unknown sampling.

    Example:
        >>> from prismstereo.classical.defaults import resolve_level
        >>> from prismstereo.epipolar.sweep import fit_sweep
        >>> rig = thesis_setup1().downscaled(8); fit = fit_sweep(rig, (400.0, 700.0))
        >>> uv = torch.stack(torch.meshgrid(torch.arange(64.0), torch.arange(96.0), indexing="xy"), -1).double()
        >>> fine = sweep_coefficients(fit, uv).permute(2, 0, 1, 3)
        >>> config = resolve_level(rig, (400.0, 700.0), StereoConfig())
        >>> built = build_search(rig, fit, fine, config, torch.ones(96, 64, dtype=torch.bool))
        >>> built.search.num_hypotheses, built.rectification_residual_px
        (15, None)
    """
    search = config.search
    sampling, factor = check_option(search.sampling, ("rectified", "sweep"), "sampling"), search.coarse_factor
    h, w_ref = rig.image_height, rig.reference_width
    if sampling == "rectified":  # a 1-D shift volume on row-rectified halves
        rect = fit_row_rectification(rig, fit)
        level = rectified_level(rect, fit, factor, other_valid)
        searcher = RectifiedSearch(config.decision_options(), level, factor, w_ref, search.lr_threshold)
        return BuiltSearch(searcher, rect.max_residual_px)
    if factor == 1:
        sampler = sweep_sampler(fit, search.num_hypotheses, other_start=w_ref, other_valid=other_valid,
                                precompute=False, dtype=torch.float32, coefficients=fine)
        return BuiltSearch(SweepSearch(config.decision_options(), sampler), None)
    # the coarse grid is fixed, so is the validity of its samples: (D_c, H_c, W_c) bool
    coarse = sweep_coefficients(fit, block_centres(math.ceil(h / factor), math.ceil(w_ref / factor), factor,
                                                   fit.coefficients)).permute(2, 0, 1, 3)
    sampler = sweep_sampler(fit, sweep_hypotheses(coarse / factor), factor=factor, other_start=w_ref,
                            other_valid=level_coverage(other_valid, factor) > 0.999, dtype=torch.float32,
                            coefficients=coarse)
    return BuiltSearch(SweepSearch(config.decision_options(), sampler), None)
