"""The matching stages: split the capture, build cost volumes, aggregate, select hypotheses, post-process estimates,
judge them. Operations only, each taking its stage's options (:mod:`~prismstereo.matching.options`); the models that
compose them are :mod:`prismstereo.classical` and :mod:`prismstereo.learned`.

The classical chain's path: :class:`SplitImage`, the coarse level (:mod:`~prismstereo.matching.search`:
:class:`RectifiedSearch` / :class:`SweepSearch` with :class:`SweepSampler`, the plane sweep's sampling that
:class:`~prismstereo.nn.PrismCostVolume` shares, :func:`sweep_cost` / :func:`shift_cost`, and one :func:`decide`:
:func:`box_filter`, :func:`sgm_aggregate`, winner, sub-pixel fit), the fine bands (:mod:`~prismstereo.matching.band`:
:class:`FineBand`), the smoothing (:func:`robust_mean`) and the calibrated confidence
(:class:`ConfidenceModel`), the z-buffer occlusion test (:func:`zbuffer_visible`). The rectified-pair matcher
(``prismstereo match``, :mod:`~prismstereo.classical.rectified`) runs on the same :func:`shift_cost` and
:func:`decide`, with its own post-processing.
"""

from prismstereo.matching.aggregate import box_filter, box_std, guided_filter, sgm_aggregate, sgm_aggregate_guided
from prismstereo.matching.band import FineBand, extend_estimate
from prismstereo.matching.confidence import (
    FEATURES,
    SMOOTHED_FEATURES,
    ConfidenceModel,
    confidence_features,
    fit_confidence,
    local_spread,
    smoothed_features,
)
from prismstereo.matching.cost import (
    COSTS,
    Cost,
    Warped,
    census_transform,
    sweep_cost,
    worst_cost,
)
from prismstereo.matching.occlusion import zbuffer_visible
from prismstereo.matching.options import AggregationConfig, BandOptions, CostConfig, DecisionOptions
from prismstereo.matching.postprocess import RobustMean, fill_background, median_filter, robust_mean, weighted_median
from prismstereo.matching.search import (
    Decision,
    LevelResult,
    RectifiedSearch,
    SweepSearch,
    decide,
)
from prismstereo.matching.select import (
    Subpixel,
    left_right_check,
    refine,
    soft_argmin_local,
    subpixel_refine,
    subpixel_refine_guarded,
    uniqueness,
    winner_take_all,
)
from prismstereo.matching.split import Halves, SplitImage
from prismstereo.matching.sweep_cost import sample_slices, shift_cost, warp_slices
from prismstereo.matching.sweep_sampler import SweepSampler, sweep_sampler

__all__ = [
    "SplitImage",
    "Halves",
    "SweepSearch",
    "RectifiedSearch",
    "decide",
    "Decision",
    "FineBand",
    "LevelResult",
    "extend_estimate",
    "Warped",
    "sample_slices",
    "warp_slices",
    "SweepSampler",
    "sweep_sampler",
    "sweep_cost",
    "worst_cost",
    "shift_cost",
    "robust_mean",
    "RobustMean",
    "FEATURES",
    "SMOOTHED_FEATURES",
    "ConfidenceModel",
    "confidence_features",
    "local_spread",
    "smoothed_features",
    "fit_confidence",
    "COSTS",
    "Cost",
    "box_filter",
    "box_std",
    "guided_filter",
    "sgm_aggregate",
    "sgm_aggregate_guided",
    "census_transform",
    "fill_background",
    "median_filter",
    "weighted_median",
    "Subpixel",
    "left_right_check",
    "soft_argmin_local",
    "subpixel_refine",
    "refine",
    "subpixel_refine_guarded",
    "uniqueness",
    "winner_take_all",
    "zbuffer_visible",
    "AggregationConfig",
    "BandOptions",
    "CostConfig",
    "DecisionOptions",
]
