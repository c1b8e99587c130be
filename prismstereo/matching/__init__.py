"""Matching layers: split the capture, build cost volumes, select hypotheses."""

from prismstereo.matching.aggregate import box_filter, sgm_aggregate
from prismstereo.matching.cost import COSTS, Cost, CostVolume, census_transform, cost_volume, shifted
from prismstereo.matching.select import (
    Subpixel,
    left_right_check,
    soft_argmin_local,
    subpixel_refine,
    uniqueness,
    winner_take_all,
)
from prismstereo.matching.split import Halves, SplitImage

__all__ = [
    "COSTS",
    "Cost",
    "CostVolume",
    "box_filter",
    "sgm_aggregate",
    "census_transform",
    "cost_volume",
    "shifted",
    "Subpixel",
    "left_right_check",
    "soft_argmin_local",
    "subpixel_refine",
    "uniqueness",
    "winner_take_all",
    "Halves",
    "SplitImage",
]
