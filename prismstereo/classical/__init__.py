"""The classical chain: the exact plane sweep searched, refined and judged by window costs, coarse to fine.

:class:`PrismStereo` (the model) composes :class:`~prismstereo.classical.level.DepthLevel` s, each the whole chain
at one resolution, built from a :class:`StereoConfig` (options grouped by stage, named :data:`PRESETS`) whose None
options :func:`resolve_config` picks by rule (:mod:`prismstereo.classical.defaults`). :class:`TemporalDepth` places
the model's band on the previous frame of a video instead (:mod:`prismstereo.classical.temporal`, its options and
prior in :mod:`prismstereo.classical.prior`). :func:`~prismstereo.classical.rectified.match_rectified` runs the
same matching on a conventional rectified pair.

The names are imported on first use (PEP 562): a process that only runs exported graphs imports the temporal
prior's options and data, not the chain.
"""

from prismstereo.lazy import lazy_names

__all__ = ["PRESETS", "BandPrior", "PrismStereo", "ResolvedConfig", "StereoConfig", "TemporalDepth",
           "TemporalOptions", "TrackedDepth", "as_config", "band_prior", "preset", "resolve_config"]

_LAZY = {
    "PRESETS": "config", "StereoConfig": "config", "as_config": "config", "preset": "config",
    "ResolvedConfig": "defaults", "resolve_config": "defaults",
    "PrismStereo": "model",
    "TemporalDepth": "temporal",
    "BandPrior": "prior", "TemporalOptions": "prior", "TrackedDepth": "prior", "band_prior": "prior",
}


__getattr__, __dir__ = lazy_names(__name__, {k: f"prismstereo.classical.{v}" for k, v in _LAZY.items()}, __all__)
