"""The depth model's options grouped by stage, with named presets and a JSON form.

:class:`StereoConfig` holds every option of :class:`~prismstereo.classical.model.PrismStereo` in five groups — where and
how finely the sweep is searched (:class:`SearchConfig`), the matching cost (:class:`CostConfig`), the aggregation
(:class:`AggregationConfig`), the sub-pixel refinement (:class:`RefinementConfig`) and what counts as a valid
depth (:class:`ValidityConfig`) — with the model's defaults. Presets name the settings users pick between:

The ``cost`` and ``aggregation`` groups are the matching stages' own options
(:class:`~prismstereo.matching.options.CostConfig`, :class:`~prismstereo.matching.options.AggregationConfig`).

* ``'accurate'``: the default (a 2 x 2-binned model places a full-resolution band on large sensors, calibrated
  confidence);
* ``'fast'``: a 2 x 2-binned model, then a full-resolution band of 3 hypotheses with its edges clamped
  (``downsample=2, full_band=1, band_edges='clamp'``), with confidence weights fitted to clamped bands
  (:data:`~prismstereo.matching.confidence.CLAMPED_WEIGHTS`);
* ``'dense'``: a depth for every pixel of the common field of view with its confidence (``dense=True``), and a
  coarse level that carries matches into weakly textured regions: finer (``coarse_factor=2``: the binned model's
  search at 1/4 of the sensor instead of 1/8) and matched by cost-volume filtering (``cost='ad_gradient'``,
  ``aggregation='guided'``, ``box=1``: a per-pixel cost aggregated by a guided filter of the reference, which
  spreads evidence through regions of even grey and stops at edges);
* ``'reference'``: one exact full-resolution level over the whole range (no coarse-to-fine placement): slow,
  the baseline the others are measured against.

``PrismStereo(rig, z_range_mm, config)`` builds the model from a config, a preset's name or a dict of options on
top of the default (``{"coarse_factor": 1}``; :meth:`StereoConfig.with_options` on any config); ``prismstereo
depth`` and ``export`` take ``--preset NAME`` and ``--config FILE.json``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from prismstereo.errors import OptionError, check_int, check_number, check_odd, check_option
from prismstereo.matching.options import (
    BAND_EDGES,
    REFINEMENTS,
    AggregationConfig,
    BandOptions,
    CostConfig,
    DecisionOptions,
)

__all__ = ["SearchConfig", "RefinementConfig", "ValidityConfig", "StereoConfig", "PRESETS", "as_config", "preset"]

VALIDITIES: tuple[str, ...] = ("calibrated", "thresholds")
CONFIDENCE_WEIGHTS: tuple[str, ...] = ("default", "clamped")
SAMPLINGS: tuple[str, ...] = ("sweep", "rectified")


@dataclasses.dataclass(frozen=True, kw_only=True)
class SearchConfig:
    """Where the sweep is searched and at which resolution (the rules behind the None defaults:
    :mod:`prismstereo.classical.defaults`).

    Attributes:
        num_hypotheses: D at full resolution (of the binned image with ``downsample`` > 1), uniform in 1/Z;
            None: neighbours <= 1 px apart.
        downsample: k > 1 matches on the capture box-averaged over k x k pixel blocks (the rig seen through that
            binning, :meth:`~prismstereo.geometry.rig.BiPrismRig.binned`) and returns the depth on the
            full-resolution reference grid: re-estimated there by a band of 2 ``full_band`` + 1 hypotheses (the
            pyramid), or with ``full_band`` 0 each pixel with its block's values. None: 2 with ``full_band`` 2
            when the reference half is >= 384 px on its shorter side, else 1.
        full_band: R > 0 with ``downsample`` k > 1: the binned level's estimate places a band of 2 R + 1
            hypotheses (<= 1 px apart) at full resolution around every pixel; 0: block values; None: 2 with the
            default ``downsample`` when that is > 1, else 0.
        coarse_factor: f, the coarse level's box downsampling (1: one full-resolution level over the whole
            range); None: the largest power of two <= 4 leaving >= 24 hypotheses (12 in a pyramid's binned
            level) and >= 32 rows and columns.
        band: R of the fine band after the coarse level, s0 + j step for j = -R..R; None: f + 1 (ceil(3 f / 4)
            in a pyramid's binned level, whose estimate only places the full-resolution band).
        band_edges: a fine band's pixel whose best hypothesis is on the band's edge (its match lies beyond the
            band): 'reject' makes it invalid; 'clamp' refines at the edge's inner neighbour (every band, with the
            confidence weights of the fast setting, a full-resolution band of 3); None: a band clamps where the
            calibrated confidence judges its pixels (the final band of a coarse-to-fine model) and rejects where
            thresholds do (a pyramid's binned level, which only places the final band; ``validity='thresholds'``):
            more coverage on planes, under defocus and on photographs than 'reject' everywhere, slightly more
            false matches.
        sampling: how the coarse (or single) level samples the other half: 'rectified' (a 1-D shift volume on
            row-rectified halves) or 'sweep' (the exact per-pixel plane sweep); None: 'rectified' for a coarse
            level, 'sweep' for a single level.
        coarse_reach: invalid coarse pixels within this many coarse pixels of valid ones take their valid
            neighbours' mean estimate before it places the fine band (0: off).
        lr_threshold: left-right check of the rectified level: the other half's winners must agree with the
            reference's to this many level pixels; None: no check.
    """

    num_hypotheses: int | None = None
    downsample: int | None = None
    full_band: int | None = None
    coarse_factor: int | None = None
    band: int | None = None
    band_edges: str | None = None
    sampling: str | None = None
    coarse_reach: int = 1
    lr_threshold: float | None = None

    def __post_init__(self) -> None:
        if self.band_edges is not None:
            check_option(self.band_edges, BAND_EDGES, "band_edges")
        if self.sampling is not None:
            check_option(self.sampling, SAMPLINGS, "sampling")
        check_int(self.num_hypotheses, "num_hypotheses", 2, none=True)
        check_int(self.downsample, "downsample", 1, none=True)
        check_int(self.full_band, "full_band", 0, none=True)
        check_int(self.coarse_factor, "coarse_factor", 1, none=True)
        check_int(self.band, "band", 1, none=True)
        check_int(self.coarse_reach, "coarse_reach", 0)
        check_number(self.lr_threshold, "lr_threshold", 0.0, math.inf, "> 0", none=True, open_low=True)


@dataclasses.dataclass(frozen=True, kw_only=True)
class RefinementConfig:
    """Sub-pixel refinement and smoothing of the final estimate.

    Attributes:
        refinement: None picks the fit matching each level's cost (equiangular for census / SAD, parabola for
            ZNCC); 'equiangular', 'parabola' or 'soft_argmin' (a local soft-argmin, differentiable w.r.t. the
            cost).
        smoothing: the estimate becomes the confidence-weighted mean of the estimates within a ``smoothing`` x
            ``smoothing`` window that agree with the window's mean to ``smoothing_tolerance`` hypothesis steps
            (:func:`~prismstereo.matching.postprocess.robust_mean`; 0: off): depth steps stay, confident pixels
            that disagree (thin structures) keep their own estimate.
        smoothing_tolerance: see ``smoothing`` (hypothesis steps, > 0).
    """

    refinement: str | None = None
    smoothing: int = 15
    smoothing_tolerance: float = 4.0

    def __post_init__(self) -> None:
        if self.refinement is not None:
            check_option(self.refinement, REFINEMENTS, "refinement")
        check_odd(self.smoothing, "smoothing", 3, zero=True)
        check_number(self.smoothing_tolerance, "smoothing_tolerance", 0.0, math.inf, "a finite number > 0",
                open_low=True)


@dataclasses.dataclass(frozen=True, kw_only=True)
class ValidityConfig:
    """What makes a depth valid, and the dense output.

    Attributes:
        validity: 'calibrated' (None's choice for coarse-to-fine models): the confidence is the probability that
            the depth is within 1 % of the truth (:mod:`prismstereo.matching.confidence`, fitted by
            ``benchmarks/fit_confidence.py``); 'thresholds' (None's choice for single levels): the final NCC,
            ``min_uniqueness`` and ``reach_confidence`` rules.
        min_confidence: pixels with a lower confidence are invalid.
        min_uniqueness: with 'thresholds': pixels whose coarse (or single) level winner has 1 - best / second
            best aggregated cost (outside winner +- 1) below this are invalid.
        reach_confidence: with 'thresholds': the final NCC a pixel needs when only its coarse neighbours were
            valid.
        occlusion_tolerance: relative depth margin of the z-buffer occlusion test in the other half; None: no test.
        occluder_confidence: only valid pixels with at least this confidence occlude others (None: every valid
            pixel).
        dense: a depth and a confidence for every pixel of the common field of view the final band can sample
            (``confidence`` > 0 exactly there); ``valid`` stays the mask of the confident pixels. Needs a
            coarse-to-fine model.
        dense_fill: with ``dense``, pixels that are not valid take the mean estimate of the valid pixels within
            this many pixels (0: their own estimates).
        confidence_weights: which fitted weights the calibrated confidence uses: 'default'
            (:data:`~prismstereo.matching.confidence.DEFAULT_WEIGHTS`, fitted on final bands that reject their edges)
            or 'clamped' (:data:`~prismstereo.matching.confidence.CLAMPED_WEIGHTS`, fitted on bands asked to clamp
            them); None: 'clamped' when ``band_edges='clamp'`` is asked for a model that is not dense, else 'default'.
    """

    validity: str | None = None
    min_confidence: float = 0.5
    min_uniqueness: float = 0.3
    reach_confidence: float = 0.9
    occlusion_tolerance: float | None = 0.01
    occluder_confidence: float | None = 0.8
    dense: bool = False
    dense_fill: int = 15
    confidence_weights: str | None = None

    def __post_init__(self) -> None:
        if self.validity is not None:
            check_option(self.validity, VALIDITIES, "validity")
        if self.confidence_weights is not None:
            check_option(self.confidence_weights, CONFIDENCE_WEIGHTS, "confidence_weights")
        if not isinstance(self.dense, bool):
            raise OptionError(f"dense must be a bool, got {self.dense!r}")
        check_int(self.dense_fill, "dense_fill", 0)
        check_number(self.occluder_confidence, "occluder_confidence", 0.0, 1.0, "in [0, 1]", none=True)
        check_number(self.reach_confidence, "reach_confidence", 0.0, 1.0, "in [0, 1]")


_GROUPS: dict[str, type] = {"search": SearchConfig, "cost": CostConfig, "aggregation": AggregationConfig,
                            "refinement": RefinementConfig, "validity": ValidityConfig}


@dataclasses.dataclass(frozen=True, kw_only=True)
class StereoConfig:
    """Every option of :class:`~prismstereo.classical.model.PrismStereo`, grouped by stage; the defaults are the
    model's.

    Each group checks its option values when it is built (:class:`~prismstereo.errors.OptionError`); what depends
    on the rig (a coarse factor or binning leaving too few rows) is checked by the model.

    Example:
        >>> config = preset("fast")
        >>> config.search.full_band, config.search.band_edges
        (1, 'clamp')
        >>> StereoConfig.from_dict(config.to_dict()) == config
        True
        >>> config.replace(validity={"dense": True}).validity.dense
        True
    """

    search: SearchConfig = dataclasses.field(default_factory=SearchConfig)
    cost: CostConfig = dataclasses.field(default_factory=CostConfig)
    aggregation: AggregationConfig = dataclasses.field(default_factory=AggregationConfig)
    refinement: RefinementConfig = dataclasses.field(default_factory=RefinementConfig)
    validity: ValidityConfig = dataclasses.field(default_factory=ValidityConfig)

    def decision_options(self) -> DecisionOptions:
        """What a level's whole-range search decides with (:func:`~prismstereo.matching.search.decide`): the cost,
        the aggregation, the final fit and the uniqueness.

        Example:
            >>> StereoConfig().decision_options().aggregation.aggregation
            'sgm'
        """
        return DecisionOptions(self.cost, self.aggregation, self.refinement.refinement, self.validity.min_uniqueness)

    def band_options(self) -> BandOptions:
        """What a level's fine band needs (:class:`~prismstereo.matching.band.FineBand`), from a resolved config
        (:func:`~prismstereo.classical.defaults.resolve_level`).

        Raises:
            OptionError: ``band_edges`` or ``refinement`` not resolved.

        Example:
            >>> preset("fast").replace(refinement={"refinement": "parabola"}).band_options().band_edges
            'clamp'
        """
        return BandOptions(self.cost, self.aggregation, self.search.band_edges, self.refinement.refinement).checked()

    def to_options(self) -> dict[str, Any]:
        """The options, flat (the inverse of :meth:`with_options` on the default config).

        Example:
            >>> StereoConfig().with_options(**preset("fast").to_options()) == preset("fast")
            True
        """
        out: dict[str, Any] = {}
        for name in _GROUPS:
            out.update(dataclasses.asdict(getattr(self, name)))
        return out

    def with_options(self, **options: Any) -> StereoConfig:
        """A copy with some options changed by their flat names: ``preset("fast").with_options(smoothing=0)``.

        Raises:
            OptionError: an unknown option name.

        Example:
            >>> preset("fast").with_options(smoothing=0).refinement.smoothing
            0
        """
        owner = _owners()
        groups: dict[str, dict[str, Any]] = {}
        for key, value in options.items():
            if key not in owner:
                raise OptionError(f"unknown option {key!r}; valid: {', '.join(sorted(owner))}")
            groups.setdefault(owner[key], {})[key] = value
        return self.replace(**groups)

    def replace(self, **groups: dict[str, Any]) -> StereoConfig:
        """A copy with some options of some groups changed: ``replace(search={"full_band": 1})``.

        Raises:
            OptionError: an unknown group or option.
        """
        changed = {}
        for group, values in groups.items():
            if group not in _GROUPS:
                raise OptionError(f"unknown config group {group!r}; valid: {', '.join(_GROUPS)}")
            try:
                changed[group] = dataclasses.replace(getattr(self, group), **values)
            except TypeError as exc:
                raise OptionError(f"config group {group!r}: {exc}") from exc
        return dataclasses.replace(self, **changed)

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """A JSON-ready dict of the groups."""
        return {name: dataclasses.asdict(getattr(self, name)) for name in _GROUPS}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> StereoConfig:
        """The inverse of :meth:`to_dict` (missing groups and options take their defaults).

        Raises:
            OptionError: not a dict of groups, an unknown group or option.
        """
        if not isinstance(data, dict):
            raise OptionError(f"a config must be a JSON object of groups ({', '.join(_GROUPS)}), got "
                              f"{type(data).__name__}")
        return cls().replace(**{k: (v if isinstance(v, dict) else _not_a_group(k, v)) for k, v in data.items()})

    def to_json(self, path: str | Path) -> None:
        """Write :meth:`to_dict` as JSON."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def from_json(cls, path: str | Path) -> StereoConfig:
        """Read a config written by :meth:`to_json` (or by hand: only the options that differ are needed).

        Raises:
            OptionError: a missing or unreadable file, or a bad config.
        """
        try:
            data = json.loads(Path(path).read_text())
        except (OSError, ValueError) as exc:
            raise OptionError(f"cannot read the config {path}: {exc}") from exc
        return cls.from_dict(data)


def _owners() -> dict[str, str]:
    """Each option's group."""
    return {f.name: g for g, kind in _GROUPS.items() for f in dataclasses.fields(kind)}


def _not_a_group(name: str, value: Any) -> dict[str, Any]:
    raise OptionError(f"config group {name!r} must be an object of options, got {value!r}")


PRESETS: dict[str, StereoConfig] = {
    "accurate": StereoConfig(),
    "fast": StereoConfig(search=SearchConfig(downsample=2, full_band=1, band_edges="clamp")),
    "dense": StereoConfig(search=SearchConfig(coarse_factor=2), cost=CostConfig(cost="ad_gradient"),
                          aggregation=AggregationConfig(aggregation="guided", box=1),
                          validity=ValidityConfig(dense=True)),
    "reference": StereoConfig(search=SearchConfig(downsample=1, coarse_factor=1)),
}


def as_config(config: StereoConfig | str | Mapping[str, Any] | None) -> StereoConfig:
    """The :class:`StereoConfig` a model's ``config`` argument names: a config as it is, a preset's name
    (:func:`preset`), a dict of flat options on top of the default (:meth:`StereoConfig.with_options`) or None
    (the default, 'accurate').

    Raises:
        OptionError: anything else, an unknown preset or option, a bad value.

    Example:
        >>> as_config({"coarse_factor": 1}).search.coarse_factor, as_config("fast") == preset("fast")
        (1, True)
    """
    if config is None:
        return PRESETS["accurate"]
    if isinstance(config, str):
        return preset(config)
    if isinstance(config, Mapping):
        return StereoConfig().with_options(**config)
    if not isinstance(config, StereoConfig):
        raise OptionError(f"config must be a StereoConfig, a preset name or a dict of options, got "
                          f"{type(config).__name__}")
    return config


def preset(name: str) -> StereoConfig:
    """A named preset (:data:`PRESETS`: 'accurate', 'fast', 'dense', 'reference').

    Raises:
        OptionError: an unknown name, listing the valid ones.

    Example:
        >>> preset("dense").validity.dense
        True
    """
    if name not in PRESETS:
        raise OptionError(f"unknown preset {name!r}. Choose from: {', '.join(PRESETS)}")
    return PRESETS[name]
