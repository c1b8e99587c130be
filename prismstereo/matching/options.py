"""The options of the matching stages: what a cost and an aggregation take, and what a search's decision and a fine
band need of a level's options.

The stage operations of :mod:`prismstereo.matching` take these, not a model's whole configuration: the classical
chain's :class:`~prismstereo.classical.config.StereoConfig` groups them (its ``cost`` and ``aggregation``
groups are :class:`CostConfig` and :class:`AggregationConfig`) and hands each stage its part
(:meth:`~prismstereo.classical.config.StereoConfig.decision_options`,
:meth:`~prismstereo.classical.config.StereoConfig.band_options`); the rectified-pair matcher hands its own.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

from prismstereo.errors import OptionError, check_int, check_number, check_odd, check_option
from prismstereo.matching.aggregate import GUIDED_EPS, GUIDED_RADIUS, GUIDED_SUBSAMPLE
from prismstereo.matching.cost import COSTS

__all__ = ["AGGREGATIONS", "AggregationConfig", "BAND_EDGES", "BandOptions", "CostConfig", "DecisionOptions",
           "REFINEMENTS"]

AGGREGATIONS: tuple[str, ...] = ("sgm", "box", "guided")
REFINEMENTS: tuple[str, ...] = ("equiangular", "parabola", "soft_argmin")
BAND_EDGES: tuple[str, ...] = ("reject", "clamp")


@dataclasses.dataclass(frozen=True, kw_only=True)
class CostConfig:
    """The matching costs (:mod:`prismstereo.matching.sweep_cost`).

    Attributes:
        cost: the coarse (or single) level's cost: 'zncc' (invariant to gain and offset differences between the
            halves), 'census', 'sad' or 'ad_gradient' (a truncated grey and horizontal-gradient difference per pixel,
            for the 'guided' aggregation).
        fine_cost: the fine band's cost ('zncc': sub-pixel accurate with the parabola fit), one of the same.
        window: census / ZNCC window (odd).
        census_threshold: census bits count neighbours darker than the centre by more than this (the default
            keeps torch and onnxruntime bitwise equal on 8-bit captures).
    """

    cost: str = "zncc"
    fine_cost: str = "zncc"
    window: int = 5
    census_threshold: float = 0.4 / 255

    def __post_init__(self) -> None:
        check_option(self.cost, COSTS, "cost")
        check_option(self.fine_cost, COSTS, "fine_cost")
        check_odd(self.window, "window")
        check_number(self.census_threshold, "census_threshold", 0.0, math.inf, "a number >= 0")


@dataclasses.dataclass(frozen=True, kw_only=True)
class AggregationConfig:
    """Box and semi-global aggregation of the costs (:mod:`prismstereo.matching.aggregate`).

    Attributes:
        aggregation: 'sgm' (semi-global after the box), 'box', or 'guided': a guided filter of the coarse (or
            single) level's volume, steered by its grey reference (carries the evidence through regions of even
            grey, stops at edges; with ``cost='ad_gradient', box=1`` it is Rhemann et al.'s cost-volume filtering).
            The fine bands keep their box either way.
        box: box window of the coarse (or single) level.
        fine_box: box window of the fine band.
        directions: SGM scan directions: 2, 4 (horizontal and vertical) or 8.
        p1, p2: SGM penalties in units of the box-averaged cost (ZNCC: 1 - NCC in [0, 2]).
        p2_edge: None for a constant P2; else the guide's intensity step (image units, > 0) that halves P2 between
            neighbours, P2 / (1 + |dI| / p2_edge) but at least P1 (depth jumps are cheaper across edges,
            :func:`~prismstereo.matching.aggregate.sgm_aggregate_guided`).
        guided_radius: the guided filter's box radius r (level px, >= 1; window 2 r + 1).
        guided_eps: its regularisation (> 0, squared image units): larger smooths across weaker edges.
        guided_subsample: s >= 1: its coefficients are computed on s x s block means (the fast guided filter; 1 is
            the exact filter); the output keeps the full-resolution edges of the guide
            (:func:`~prismstereo.matching.aggregate.guided_filter`).
        wide_box: where the reference has little texture, the final band's cost is blended with the cost over
            this wider box (0: off; not in a pyramid's binned level, which only places the band).
        weak_texture: the grey standard deviation over the cost window below which that blend starts.
    """

    aggregation: str = "sgm"
    box: int = 5
    fine_box: int = 7
    directions: int = 4
    p1: float = 1.0
    p2: float = 8.0
    p2_edge: float | None = None
    guided_radius: int = GUIDED_RADIUS
    guided_eps: float = GUIDED_EPS
    guided_subsample: int = GUIDED_SUBSAMPLE
    wide_box: int = 21
    weak_texture: float = 8.0 / 255

    def __post_init__(self) -> None:
        check_option(self.aggregation, AGGREGATIONS, "aggregation")
        check_odd(self.box, "box")
        check_odd(self.fine_box, "fine_box")
        check_odd(self.wide_box, "wide_box", zero=True)
        check_number(self.weak_texture, "weak_texture", 0.0, math.inf, "a finite number > 0", open_low=True)
        if self.directions not in (2, 4, 8):
            raise OptionError(f"directions must be 2, 4 or 8, got {self.directions!r}")
        check_number(self.p1, "p1", 0.0, math.inf, "a finite number >= 0")
        check_number(self.p2, "p2", self.p1, math.inf, f"a finite number >= p1 ({self.p1})")
        check_number(self.p2_edge, "p2_edge", 0.0, math.inf, "a finite number > 0", none=True, open_low=True)
        check_int(self.guided_radius, "guided_radius", 1)
        check_number(self.guided_eps, "guided_eps", 0.0, math.inf, "a finite number > 0", open_low=True)
        check_int(self.guided_subsample, "guided_subsample", 1)


class DecisionOptions(NamedTuple):
    """What :func:`~prismstereo.matching.search.decide` (and so a whole-range search) decides with.

    Attributes:
        cost: the volume's cost (``cost``, ``window``: the confidence's worst cost).
        aggregation: the aggregation of the volume.
        refinement: the sub-pixel fit of a final search ('equiangular', 'parabola', 'soft_argmin'); None: the fit
            matching the cost (a placement always takes that one).
        min_uniqueness: the uniqueness a winner needs (best / second-best ratio test).

    Example:
        >>> DecisionOptions(CostConfig(), AggregationConfig()).min_uniqueness
        0.3
    """

    cost: CostConfig
    aggregation: AggregationConfig
    refinement: str | None = None
    min_uniqueness: float = 0.3


class BandOptions(NamedTuple):
    """What a :class:`~prismstereo.matching.band.FineBand` needs of a level's resolved options.

    Attributes:
        cost: the band's cost is ``fine_cost`` (``window``, ``census_threshold``).
        aggregation: its box ``fine_box``, ``wide_box`` and ``weak_texture``.
        band_edges: 'reject' or 'clamp' (:data:`BAND_EDGES`).
        refinement: the sub-pixel fit, 'equiangular', 'parabola' or 'soft_argmin'.

    Raises:
        OptionError: an unknown ``band_edges`` or ``refinement`` (checked by :meth:`checked`).

    Example:
        >>> BandOptions(CostConfig(), AggregationConfig(), "clamp", "parabola").checked().band_edges
        'clamp'
    """

    cost: CostConfig
    aggregation: AggregationConfig
    band_edges: str
    refinement: str

    def checked(self) -> BandOptions:
        """These options, their ``band_edges`` and ``refinement`` checked (both must be set: a resolved level's)."""
        if self.band_edges is None or self.refinement is None:
            raise OptionError("a fine band needs resolved options (prismstereo.classical.defaults.resolve_level): "
                              "band_edges and refinement set")
        check_option(self.band_edges, BAND_EDGES, "band_edges")
        check_option(self.refinement, REFINEMENTS, "refinement")
        return self
