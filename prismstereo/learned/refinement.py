"""The hybrid's learned refinement stage: its hyper-parameters (:class:`HybridArchitecture`, stored beside the weights),
the configuration of its classical level (:func:`classical_config`) and its CNN (:class:`RefinementCNN`), a dilated
3 x 3 network in the manner of StereoNet's and HITNet's refinements that reads the reference image, the cost curve
around the estimate on the exact sweep, the estimate's relief and the classical confidence, and predicts a residual and
a confidence logit (:class:`~prismstereo.learned.hybrid.HybridStereo` composes them).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.classical import StereoConfig, preset
from prismstereo.errors import OptionError, check_int

__all__ = ["DILATIONS", "STARTS", "HybridArchitecture", "RefinementCNN", "RefinementInputs", "classical_config"]

STARTS = ("classical", "learned")
"""What the refinement stages start from (:attr:`HybridArchitecture.start`)."""

DILATIONS = (1, 2, 4, 8, 1, 1, 1, 1)
"""The dilations of a CNN's 3 x 3 convolutions, layer by layer (the receptive field doubles over the first four)."""


@dataclasses.dataclass(frozen=True)
class HybridArchitecture:
    """The hyper-parameters that shape the weights (stored beside them).

    Attributes:
        block: k, the classical level's bins in units of half a pixel of the stages' grid (2 or 4: 2 x 2 or 4 x 4
            bins of a sensor whose stages run 2 x 2-binned, half that where they run at full resolution;
            :attr:`~prismstereo.learned.hybrid.HybridStereo.binning`).
        channels: C, channels of each refinement CNN.
        layers: 3 x 3 convolutions per CNN (2-8, dilations 1, 2, 4, 8, 1, ...), the output head included.
        offsets: the cost curve is sampled at s + o steps for o = -offsets ... +offsets.
        iterations: refinement stages on the stages' grid, each with its own CNN (0: the last stage is on the
            classical level's grid, its estimate carried over bilinearly; needs ``quarter`` >= 1).
        quarter: refinement stages on the classical level's grid before them (block 4 only: twice the reach per
            layer).
        start: what the stages start from: ``'learned'`` (the learned first stage,
            :class:`~prismstereo.learned.sweep_start.SweepStart`, on 4 x 4 cells of the stages' grid; block 4 only) or
            ``'classical'`` (the classical block level).

    Example:
        >>> HybridArchitecture().block, HybridArchitecture(offsets=1).inputs
        (4, 8)
    """

    block: int = 4
    channels: int = 16
    layers: int = 5
    offsets: int = 2
    iterations: int = 1
    quarter: int = 1
    start: str = "learned"

    def __post_init__(self) -> None:
        if self.block not in (2, 4):
            raise OptionError(f"Unknown block {self.block!r}. Choose from: 2, 4")
        for name, low, high in (("channels", 1, 256), ("layers", 2, len(DILATIONS)), ("offsets", 0, 8),
                                ("iterations", 0, 4), ("quarter", 0, 4)):
            check_int(getattr(self, name), name, low, most=high)
        if self.start not in STARTS:
            raise OptionError(f"Unknown start {self.start!r}. Choose from: {', '.join(STARTS)}")
        if self.start == "learned" and self.block != 4:
            raise OptionError(f"the learned start needs block 4, got block {self.block}")
        if not self.iterations and not self.quarter:
            raise OptionError("a hybrid needs a refinement stage: iterations or quarter >= 1")
        if self.quarter and self.block != 4:
            raise OptionError(f"quarter stages need block 4 (the classical level's grid), got block {self.block}")

    @property
    def inputs(self) -> int:
        """Input channels of a CNN: 2 image, 2 offsets + 1 costs, relief, confidence, coverage."""
        return 2 + 2 * self.offsets + 1 + 3


def _conv(cin: int, cout: int, dilation: int = 1) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, 3, padding=dilation, dilation=dilation)


class RefinementCNN(nn.Module):
    """One stage's CNN: (B, inputs, h, w) -> (B, 2, h, w), the residual in steps and the confidence logit; the head
    starts at zero, so an untrained stage keeps the classical estimate.

    Example:
        >>> RefinementCNN(HybridArchitecture())(torch.rand(1, 10, 8, 8)).abs().max().item()
        0.0
    """

    def __init__(self, arch: HybridArchitecture) -> None:
        super().__init__()
        c = arch.channels
        self.convs = nn.ModuleList([_conv(arch.inputs, c)] + [_conv(c, c, d) for d in DILATIONS[1:arch.layers - 1]])
        self.head = _conv(c, 2)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for conv in self.convs:
            x = F.leaky_relu(conv(x), 0.1)
        return self.head(x)


class RefinementInputs(NamedTuple):
    """The classical estimate on its k x k-binned grid (h_k, w_k) and the normalised capture on the stages' grid
    (:meth:`~prismstereo.learned.hybrid.HybridStereo.initial`; training computes it once per capture).

    Attributes:
        image: (B, 2, h, W2) the normalised capture on the stages' grid (both halves).
        s: (B, 1, h_k, w_k) sweep coordinate of the classical estimate; where it has none, the mean of its covered
            blocks within :data:`~prismstereo.learned.hybrid.FILL_RADIUS`
            (:func:`~prismstereo.matching.band.extend_estimate`), else 0.
        confidence: (B, 1, h_k, w_k) its calibrated confidence (0 where it has no depth).
        covered: (B, 1, h_k, w_k) 1 where it has a depth, else 0.
    """

    image: torch.Tensor
    s: torch.Tensor
    confidence: torch.Tensor
    covered: torch.Tensor


def classical_config(block: int) -> StereoConfig:
    """The hybrid's classical level: the 'dense' preset (gradient-augmented absolute differences, guided-filter
    aggregation, a coarse level at factor 2, a depth for every covered pixel) in block mode on ``block`` x ``block``
    bins.

    Example:
        >>> config = classical_config(4)
        >>> config.search.downsample, config.search.full_band, config.validity.dense
        (4, 0, True)
    """
    return preset("dense").replace(search={"downsample": block, "full_band": 0})
