"""Layers for learned bi-prism stereo: a cost volume on the exact sweep and differentiable depth regression."""

from prismstereo.nn.cost_volume import MODES, Mode, PrismCostVolume, SweepGrid, sweep_grid
from prismstereo.nn.regression import DepthRegression, depth_regression

__all__ = [
    "MODES",
    "Mode",
    "PrismCostVolume",
    "SweepGrid",
    "sweep_grid",
    "DepthRegression",
    "depth_regression",
]
