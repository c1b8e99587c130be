"""The depth models' output: :class:`DepthResult`, shared by :class:`~prismstereo.classical.model.PrismStereo`,
:class:`~prismstereo.learned.LearnedStereo` and :class:`~prismstereo.stream.DepthStream` users."""

from __future__ import annotations

from typing import NamedTuple

import torch

__all__ = ["DepthResult"]


class DepthResult(NamedTuple):
    """Depth of the reference half.

    Attributes:
        depth: (B, 1, H, W_ref) depth Z (mm); meaningless where not valid.
        valid: (B, 1, H, W_ref) bool.
        confidence: (B, 1, H, W_ref) in [0, 1]: the probability that the depth is within 1 % of the truth
            (PrismStereo with ``validity='thresholds'``: the final NCC); 0 where invalid (a dense model: 0 exactly
            where it gives no depth).
        index: (B, 1, H, W_ref) fractional index into the model's ``depths`` (uniform in 1/Z).
        match: (B, 2, H, W_ref) (u, v) of each pixel's match in the other half, full-sensor pixels (the
            generalised disparity); like the depth, meaningful where valid.
    """

    depth: torch.Tensor
    valid: torch.Tensor
    confidence: torch.Tensor
    index: torch.Tensor
    match: torch.Tensor
