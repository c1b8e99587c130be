"""The depth model's options grouped by stage, with named presets and a JSON form.

:class:`StereoConfig` holds every option of :class:`~prismstereo.model.PrismStereo` in five groups — where and how
finely the sweep is searched (:class:`SearchConfig`), the matching cost (:class:`CostConfig`), the aggregation
(:class:`AggregationConfig`), the sub-pixel refinement (:class:`RefinementConfig`) and what counts as a valid
depth (:class:`ValidityConfig`) — with the model's defaults. Presets name the settings users pick between:

* ``'accurate'``: the default (a 2 x 2-binned model places a full-resolution band on large sensors, calibrated
  confidence);
* ``'fast'``: a 2 x 2-binned model, then a full-resolution band of 3 hypotheses with its edges clamped
  (``downsample=2, full_band=1, band_edges='clamp'``), with confidence weights fitted to clamped bands
  (:data:`~prismstereo.matching.confidence.CLAMPED_WEIGHTS`);
* ``'dense'``: a depth for every pixel of the common field of view with its confidence (``dense=True``), and a
  finer coarse level (``coarse_factor=2``: the binned model's search at 1/4 of the sensor instead of 1/8, which
  finds more of the weakly textured regions, at ~1.4x the time);
* ``'reference'``: one exact full-resolution level over the whole range (no coarse-to-fine placement): slow,
  the baseline the others are measured against.

``PrismStereo.from_config(rig, z_range_mm, config)`` builds the model; ``prismstereo depth`` and ``export`` take
``--preset NAME`` and ``--config FILE.json``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from prismstereo.errors import OptionError

__all__ = [
    "SearchConfig", "CostConfig", "AggregationConfig", "RefinementConfig", "ValidityConfig", "StereoConfig",
    "PRESETS", "preset",
]


@dataclasses.dataclass(frozen=True, kw_only=True)
class SearchConfig:
    """Where the sweep is searched and at which resolution (see :class:`~prismstereo.model.PrismStereo`)."""

    num_hypotheses: int | None = None
    downsample: int | None = None
    full_band: int | None = None
    coarse_factor: int | None = None
    band: int | None = None
    band_edges: str = "reject"
    sampling: str | None = None
    coarse_reach: int = 1
    lr_threshold: float | None = None


@dataclasses.dataclass(frozen=True, kw_only=True)
class CostConfig:
    """The matching costs of the coarse level and of the final band."""

    cost: str = "zncc"
    fine_cost: str = "zncc"
    window: int = 5
    census_threshold: float = 0.4 / 255


@dataclasses.dataclass(frozen=True, kw_only=True)
class AggregationConfig:
    """Box and semi-global aggregation of the costs, and the wide box blended in where texture is weak."""

    aggregation: str = "sgm"
    box: int = 5
    fine_box: int = 7
    directions: int = 4
    p1: float = 1.0
    p2: float = 8.0
    wide_box: int = 21
    weak_texture: float = 8.0 / 255


@dataclasses.dataclass(frozen=True, kw_only=True)
class RefinementConfig:
    """The sub-pixel refinement of the final level (None: the fit matching its cost) and the smoothing of the
    estimate (a confidence-weighted robust mean over ``smoothing`` x ``smoothing`` pixels, 0: off)."""

    refinement: str | None = None
    smoothing: int = 15
    smoothing_tolerance: float = 4.0


@dataclasses.dataclass(frozen=True, kw_only=True)
class ValidityConfig:
    """What makes a depth valid, and the dense output."""

    validity: str | None = None
    min_confidence: float = 0.5
    min_uniqueness: float = 0.3
    reach_confidence: float = 0.9
    occlusion_tolerance: float | None = 0.01
    occluder_confidence: float | None = 0.8
    dense: bool = False
    dense_fill: int = 15


_GROUPS: dict[str, type] = {"search": SearchConfig, "cost": CostConfig, "aggregation": AggregationConfig,
                            "refinement": RefinementConfig, "validity": ValidityConfig}


@dataclasses.dataclass(frozen=True, kw_only=True)
class StereoConfig:
    """Every option of :class:`~prismstereo.model.PrismStereo`, grouped by stage; the defaults are the model's.

    The option values are checked by the model when it is built (:meth:`PrismStereo.from_config`); this class
    checks the structure (known groups and names).

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

    def to_kwargs(self) -> dict[str, Any]:
        """The options as :class:`~prismstereo.model.PrismStereo` keyword arguments (flat)."""
        out: dict[str, Any] = {}
        for name in _GROUPS:
            out.update(dataclasses.asdict(getattr(self, name)))
        return out

    @classmethod
    def from_kwargs(cls, **kwargs: Any) -> StereoConfig:
        """A config from flat :class:`~prismstereo.model.PrismStereo` keyword arguments (e.g. ``model.config()``).

        Raises:
            OptionError: an unknown option name.

        Example:
            >>> StereoConfig.from_kwargs(dense=True, full_band=1).search.full_band
            1
        """
        groups: dict[str, dict[str, Any]] = {name: {} for name in _GROUPS}
        owner = {f.name: g for g, kind in _GROUPS.items() for f in dataclasses.fields(kind)}
        for key, value in kwargs.items():
            if key == "z_range_mm":
                continue  # the model's range is not part of its config
            if key not in owner:
                raise OptionError(f"unknown option {key!r}; valid: {', '.join(sorted(owner))}")
            groups[owner[key]][key] = value
        return cls(**{g: _GROUPS[g](**v) for g, v in groups.items()})

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


def _not_a_group(name: str, value: Any) -> dict[str, Any]:
    raise OptionError(f"config group {name!r} must be an object of options, got {value!r}")


PRESETS: dict[str, StereoConfig] = {
    "accurate": StereoConfig(),
    "fast": StereoConfig(search=SearchConfig(downsample=2, full_band=1, band_edges="clamp")),
    "dense": StereoConfig(search=SearchConfig(coarse_factor=2), validity=ValidityConfig(dense=True)),
    "reference": StereoConfig(search=SearchConfig(downsample=1, coarse_factor=1)),
}


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
