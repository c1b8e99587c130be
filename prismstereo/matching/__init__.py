"""Matching layers: split the capture, build cost volumes, select hypotheses, post-process disparities."""

from prismstereo.matching.aggregate import box_filter, box_std, sgm_aggregate, sgm_aggregate_guided
from prismstereo.matching.confidence import (
    FEATURES,
    ConfidenceModel,
    confidence_features,
    fit_confidence,
)
from prismstereo.matching.cost import (
    COSTS,
    Cost,
    CostVolume,
    census_codes,
    census_transform,
    census_volume,
    cost_volume,
    shifted,
)
from prismstereo.matching.postprocess import fill_background, median_filter, weighted_median
from prismstereo.matching.rectified import ad_gradient_volume, guided_filter
from prismstereo.matching.select import (
    Subpixel,
    left_right_check,
    soft_argmin_local,
    subpixel_refine,
    subpixel_refine_guarded,
    uniqueness,
    winner_take_all,
)
from prismstereo.matching.split import Halves, SplitImage

__all__ = [
    "FEATURES",
    "ConfidenceModel",
    "confidence_features",
    "fit_confidence",
    "COSTS",
    "Cost",
    "CostVolume",
    "box_filter",
    "box_std",
    "sgm_aggregate",
    "sgm_aggregate_guided",
    "census_codes",
    "census_transform",
    "census_volume",
    "cost_volume",
    "shifted",
    "fill_background",
    "median_filter",
    "weighted_median",
    "ad_gradient_volume",
    "guided_filter",
    "Subpixel",
    "left_right_check",
    "soft_argmin_local",
    "subpixel_refine",
    "subpixel_refine_guarded",
    "uniqueness",
    "winner_take_all",
    "Halves",
    "SplitImage",
]
