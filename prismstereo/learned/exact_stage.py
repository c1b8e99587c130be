"""The hybrid's exact last stage: the classical band's fit on the exact sweep, placed on a learned estimate.

A learned estimate is regressed, not fitted: on textured surfaces it carries a smooth bias of about a tenth of a
sweep step (``benchmarks/default_chain.py``: ``hybrid-learned`` against ``accurate`` on textured planes). The classical
model's final band is exact there: 2 R + 1 hypotheses on each pixel's exact sweep (thesis eq. 4.1-4.10 done exactly),
ZNCC, a sub-pixel fit and a 15 x 15 confidence-weighted robust mean (:class:`~prismstereo.classical.level.DepthLevel`
with :func:`exact_config`). :class:`ExactStage` places that band (R = :data:`EXACT_BAND`) on the learned estimate, on
the grid where the classical default fits its own band (:func:`~prismstereo.classical.defaults.default_downsample`:
2 x 2-binned on sensors whose reference half is >= 384 px on its shorter side, else the full sensor), and takes its
fit where the band's NCC clears the classical threshold and the fit is within :data:`EXACT_AGREEMENT` steps of the
estimate; elsewhere (depth edges, weak texture, occlusions) the estimate stays. The learned confidence decides
validity, so the classical chain's own judges of validity (its occlusion test, its calibrated confidence) are left
out: here they would only decide which fits replace the estimate, which the agreement already bounds.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import nn

from prismstereo.classical.config import StereoConfig
from prismstereo.classical.defaults import default_downsample, resolve_level
from prismstereo.classical.level import DepthLevel
from prismstereo.errors import ShapeError, check_shape
from prismstereo.geometry.rig import BiPrismRig

__all__ = ["EXACT_AGREEMENT", "EXACT_BAND", "ExactEvidence", "ExactStage", "exact_config"]

EXACT_BAND = 1
"""R of the band: the learned estimate is within a step of the match wherever the fit replaces it, and with R = 1
the band's winner is its centre (no winner search)."""
EXACT_AGREEMENT = 0.5
"""The fit replaces the estimate where it is within this many steps of it (the band's steps)."""


def exact_config(rig: BiPrismRig, z_range_mm: tuple[float, float]) -> StereoConfig:
    """The stage's level: the classical pyramid's full-resolution level (its cost, window, sub-pixel fit and
    smoothing) placed by another estimate, band :data:`EXACT_BAND` with its edges clamped (the winner is the centre),
    valid where its NCC clears the classical threshold, no occlusion test (module docstring); resolved for ``rig``
    (the stage's grid) by :func:`~prismstereo.classical.defaults.resolve_level`.

    Example:
        >>> config = exact_config(thesis_setup1(), (450.0, 900.0))
        >>> config.search.coarse_factor, config.search.band, config.validity.validity
        (2, 1, 'thresholds')
    """
    config = StereoConfig().replace(search={"downsample": 2, "full_band": EXACT_BAND, "band_edges": "clamp"},
                                    validity={"validity": "thresholds", "occlusion_tolerance": None})
    return resolve_level(rig, z_range_mm, config, placed_by=2)


class ExactEvidence(NamedTuple):
    """What the exact stage found around an estimate, on its grid (B, 1, H', W'_ref) each (what
    :class:`~prismstereo.learned.exact_confidence.ConfidenceHead` judges the final depth by).

    Attributes:
        s: the final sweep coordinate: the fit where it was taken, else the estimate.
        similarity: the band's NCC at its fit, in [0, 1] (the classical similarity).
        taken: 1 where the fit replaced the estimate, else 0 (``s``'s dtype).
        move: how far the fit lay from the estimate, in the band's steps.
        reference: the grey reference half on the grid.
    """

    s: torch.Tensor
    similarity: torch.Tensor
    taken: torch.Tensor
    move: torch.Tensor
    reference: torch.Tensor


class ExactStage(nn.Module):
    """The classical band's fit around an estimate on the grid where the classical default fits its band (module
    docstring), the grid of the hybrid's last learned stage.

    Args:
        rig: the full-resolution rig.
        z_range_mm: (z_min, z_max) of the sweep coordinate s (the estimate's).

    Attributes:
        binning: the binning of the stage's grid (2, or 1 on sensors where the classical default has no pyramid).
        level: its :class:`~prismstereo.classical.level.DepthLevel` (the grid's rig: ``level.rig``).

    Example:
        >>> stage = ExactStage(thesis_setup1().downscaled(2), (450.0, 900.0))
        >>> s = torch.zeros(1, 1, 384, 256)  # a small sensor: the estimate and the fit at full resolution
        >>> stage.binning, stage(torch.rand(1, 1, 384, 512), s).shape
        (1, torch.Size([1, 1, 384, 256]))
    """

    def __init__(self, rig: BiPrismRig, z_range_mm: tuple[float, float]) -> None:
        super().__init__()
        self.binning = default_downsample(rig)
        grid = rig.binned(self.binning)
        self.level = DepthLevel(grid, z_range_mm, exact_config(grid, z_range_mm), placed_by=2)
        self.estimate_size = (grid.image_height, grid.reference_width)

    @property
    def rig(self) -> BiPrismRig:
        """The rig of the stage's grid."""
        return self.level.rig

    def forward(self, grey: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        """The fit around ``s``.

        Args:
            grey: (B, 1, H', W') the grey capture on the stage's grid (:attr:`rig`'s sensor).
            s: (B, 1, H', W'_ref) the estimate's sweep coordinate on the stage's grid (its reference half).

        Returns:
            (B, 1, H', W'_ref) s: the band's fit where it is valid and within :data:`EXACT_AGREEMENT` steps of the
            estimate, else the estimate.

        Raises:
            ShapeError: ``s`` or ``grey`` not on the stage's grid.
        """
        return self.evidence(grey, s).s

    def evidence(self, grey: torch.Tensor, s: torch.Tensor) -> ExactEvidence:
        """:meth:`forward` with what the band found: its NCC, where its fit was taken and how far it moved.

        Args:
            grey: (B, 1, H', W') the grey capture on the stage's grid.
            s: (B, 1, H', W'_ref) the estimate on the stage's grid.

        Returns:
            ExactEvidence of (B, 1, H', W'_ref) maps.

        Raises:
            ShapeError: ``s`` or ``grey`` not on the stage's grid.

        Example:
            >>> stage = ExactStage(thesis_setup1().downscaled(2), (450.0, 900.0))
            >>> out = stage.evidence(torch.rand(1, 1, 384, 512), torch.zeros(1, 1, 384, 256))
            >>> out.similarity.shape, bool(out.move.min() >= 0)
            (torch.Size([1, 1, 384, 256]), True)
        """
        check_shape(s, ["B", 1, *self.estimate_size], "s")
        level = self.level
        reference, other = level.split(grey)
        if reference.shape[0] != s.shape[0]:
            raise ShapeError(f"grey has {reference.shape[0]} images, s {s.shape[0]}")
        s0 = s.detach().clamp(-1.0, 1.0)
        placed = torch.ones_like(s0, dtype=torch.bool)  # every pixel has an estimate of its own
        fit = level.finish(level.search_band(reference, other, s0, placed, ~placed, None))
        fitted = fit.index * level.step - 1.0
        move = (fitted - s).abs() / level.step
        take = fit.valid & (move <= EXACT_AGREEMENT)
        return ExactEvidence(torch.where(take, fitted, s), fit.confidence, take.to(s.dtype), move, reference)
