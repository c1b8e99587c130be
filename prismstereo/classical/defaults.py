"""How :class:`~prismstereo.classical.model.PrismStereo` picks its defaults: the rules, and the one function that
applies them.

A :class:`~prismstereo.classical.config.StereoConfig` leaves some options None: "pick by rule" (the number of
hypotheses, the binning and band of the pyramid, the coarse factor, the band, the sampling, the validity, the band's
edge rule, the sub-pixel fit, the confidence weights). :func:`resolve_config` turns a rig, a depth range and a config
into a :class:`ResolvedConfig`: the model's levels, each with every option set. The model, its levels
(:class:`~prismstereo.classical.level.DepthLevel`), the temporal band and the CLI all resolve through it, so each rule
is written once, here. Why each rule is what it is, and the benchmark command that measures it: ``docs/design.md``
(*How the model picks its defaults*).
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import torch

from prismstereo.classical.config import StereoConfig
from prismstereo.errors import OptionError
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.matching.confidence import FITTED_PLACEMENT

__all__ = [
    "ResolvedConfig",
    "default_coarse_factor",
    "default_downsample",
    "default_hypotheses",
    "pyramid_band",
    "pyramid_coarse_factor",
    "resolve_config",
    "resolve_level",
]



class ResolvedConfig(NamedTuple):
    """:func:`resolve_config`'s result.

    Attributes:
        z_range_mm: (z_min, z_max) searched, mm.
        config: the config asked for, with the model-wide choices (``downsample``, ``full_band``) set: it rebuilds
            the same model (``PrismStereo(rig, z_range_mm, config)``).
        levels: each level's config with every option set, coarsest first: one level, or a pyramid's binned level
            (it places the final band) and its full-resolution level.
    """

    z_range_mm: tuple[float, float]
    config: StereoConfig
    levels: tuple[StereoConfig, ...]

    @property
    def downsample(self) -> int:
        """The binning k of the first level."""
        return self.config.search.downsample

    @property
    def full_band(self) -> int:
        """R of a pyramid's full-resolution band (0: no pyramid)."""
        return self.config.search.full_band


def resolve_config(rig: BiPrismRig, z_range_mm: tuple[float, float] | None, config: StereoConfig) -> ResolvedConfig:
    """Every option of a model of ``rig`` over ``z_range_mm`` with ``config``, its levels and their rules.

    The model-wide choices first: ``downsample`` k (:func:`default_downsample`) and ``full_band`` R (2 with the
    default k > 1, else 0). With R > 0 the model is a pyramid: the level of the k x k-binned rig (its coarse factor
    and band by the pyramid's rules, its validity by thresholds with
    :data:`~prismstereo.matching.confidence.FITTED_PLACEMENT`, no wide box, not dense: it only places the final band)
    and the full-resolution level placed by it (f = k, band R, the binned level's sampling). Otherwise one level
    (:func:`resolve_level`), on the binned rig when k > 1 (block mode).

    Args:
        rig: the sensor's rig.
        z_range_mm: (z_min, z_max); None: :func:`~prismstereo.depth.range.default_z_range`.
        config: the options asked for.

    Returns:
        ResolvedConfig.

    Raises:
        OptionError: a config that does not fit the rig: a binning leaving < 16 rows, ``full_band`` without
            binning, a level's rules (:func:`resolve_level`).

    Example:
        >>> resolved = resolve_config(thesis_setup1(), (400.0, 800.0), StereoConfig())
        >>> resolved.downsample, resolved.full_band, [c.search.num_hypotheses for c in resolved.levels]
        (2, 2, [66, 131])
    """
    from prismstereo.depth.range import default_z_range

    if not isinstance(config, StereoConfig):
        raise OptionError(f"config must be a StereoConfig, got {type(config).__name__}")
    z_range = default_z_range(rig) if z_range_mm is None else tuple(float(z) for z in z_range_mm)
    search = config.search
    k, full_band = search.downsample, search.full_band
    if k is None:  # the default: the pyramid on large sensors
        k = default_downsample(rig)
        full_band = (2 if k > 1 else 0) if full_band is None else full_band
    full_band = full_band or 0
    if rig.image_height // k < 16:
        raise OptionError(f"downsample must be an int >= 1 leaving >= 16 rows, got {k!r}")
    if full_band and k == 1:
        raise OptionError(f"full_band must be an int >= 0, and > 0 only with downsample > 1, got {full_band!r}")
    config = config.replace(search={"downsample": k, "full_band": full_band})
    if not full_band:  # one level, on the capture binned by k (block values) or at full resolution
        return ResolvedConfig(z_range, config, (resolve_level(rig.binned(k) if k > 1 else rig, z_range, config),))
    validity: dict[str, object] = {"validity": "thresholds", "dense": False}
    if config.validity.validity in (None, "calibrated"):  # the placement the confidence was fitted with
        validity.update(FITTED_PLACEMENT)
    binned = resolve_level(rig.binned(k), z_range, config.replace(validity=validity, aggregation={"wide_box": 0}),
                           places_band=True)
    final = resolve_level(rig, z_range, config.replace(search={"num_hypotheses": None,
                                                               "sampling": binned.search.sampling}), placed_by=k)
    return ResolvedConfig(z_range, config, (binned, final))


def resolve_level(rig: BiPrismRig, z_range_mm: tuple[float, float], config: StereoConfig, *, placed_by: int = 0,
                  places_band: bool = False) -> StereoConfig:
    """One level's config with every option set (a config that is already resolved comes back unchanged).

    The rules, for a level of ``rig`` (the sensor, or the sensor seen through binning):

    * ``num_hypotheses``: :func:`default_hypotheses` (neighbours <= 1 px apart on every pixel's sweep);
    * ``coarse_factor`` f: ``placed_by`` k for a level placed by a k-binned level (no search of its own), else
      :func:`default_coarse_factor` (:func:`pyramid_coarse_factor` with ``places_band``);
    * ``band`` R: the pyramid's ``full_band`` for a placed level, else f + 1 (:func:`pyramid_band` with
      ``places_band``);
    * ``validity``: 'calibrated' with f > 1, else 'thresholds'; a calibrated level's search keeps the uniqueness it
      was fitted with (:data:`~prismstereo.matching.confidence.FITTED_PLACEMENT`);
    * ``sampling``: 'rectified' with f > 1, else 'sweep';
    * ``band_edges``: 'clamp' for a dense level, else 'clamp' where the calibrated confidence judges the band's pixels
      and 'reject' where thresholds do;
    * ``refinement``: the fit matching the final cost (``fine_cost`` with f > 1, else ``cost``): 'parabola' for
      ZNCC, 'equiangular' for the others;
    * ``confidence_weights``: 'clamped' when ``band_edges='clamp'`` was asked for a level that is not dense, else
      'default'.

    Args:
        rig: the level's rig.
        z_range_mm: (z_min, z_max).
        config: the level's options.
        placed_by: k > 1: the level's band is placed by a k-binned level's estimate (a pyramid's final level).
        places_band: the level only places a pyramid's full-resolution band (the pyramid's rules).

    Returns:
        StereoConfig with no None left but ``lr_threshold``, ``occlusion_tolerance`` and ``occluder_confidence``
        (where None means "off").

    Raises:
        OptionError: a coarse factor leaving < 8 rows; a calibrated or dense single level.

    Example:
        >>> level = resolve_level(thesis_setup1().downscaled(8), (400.0, 700.0), StereoConfig())
        >>> level.search.coarse_factor, level.validity.validity, level.search.sampling
        (1, 'thresholds', 'sweep')
    """
    search, validity = config.search, config.validity
    h, w_ref = rig.image_height, rig.reference_width
    num_hypotheses = search.num_hypotheses or default_hypotheses(rig, z_range_mm)
    if placed_by:
        factor, band = placed_by, search.full_band
    else:
        rule = pyramid_coarse_factor if places_band else default_coarse_factor
        factor = search.coarse_factor or rule(num_hypotheses, h, w_ref)
        band = search.band or (pyramid_band(factor) if places_band and factor > 1 else factor + 1)
    if h // factor < 8:
        raise OptionError(f"coarse_factor must be an int >= 1 leaving >= 8 rows, got {factor!r}")
    level_validity = validity.validity or ("calibrated" if factor > 1 else "thresholds")
    if level_validity == "calibrated" and factor == 1:
        raise OptionError("validity 'calibrated' needs a coarse-to-fine model (coarse_factor > 1 or a pyramid); "
                          "a single level has 'thresholds'")
    if validity.dense and factor == 1:
        raise OptionError("dense needs a coarse-to-fine model (coarse_factor > 1 or a pyramid): a single level "
                          "has no band to place everywhere")
    calibrated = level_validity == "calibrated"
    band_edges = "clamp" if validity.dense else search.band_edges or ("clamp" if calibrated else "reject")
    final_cost = config.cost.fine_cost if factor > 1 else config.cost.cost
    refinement = config.refinement.refinement or ("parabola" if final_cost == "zncc" else "equiangular")
    weights = validity.confidence_weights or (
        "clamped" if search.band_edges == "clamp" and not validity.dense else "default")
    uniqueness = FITTED_PLACEMENT["min_uniqueness"] if calibrated else validity.min_uniqueness
    return config.replace(
        search={"num_hypotheses": num_hypotheses, "coarse_factor": factor, "band": band, "band_edges": band_edges,
                "sampling": search.sampling or ("rectified" if factor > 1 else "sweep")},
        refinement={"refinement": refinement},
        validity={"validity": level_validity, "confidence_weights": weights, "min_uniqueness": uniqueness})


def default_hypotheses(rig: BiPrismRig, z_range_mm: tuple[float, float]) -> int:
    """D, the hypotheses uniform in s over the range with neighbours <= 1 px apart on every reference pixel's sweep
    (:func:`~prismstereo.epipolar.sweep.sweep_hypotheses` on the pixels it probes).

    Args:
        rig: the level's rig.
        z_range_mm: (z_min, z_max).

    Returns:
        D.

    Example:
        >>> default_hypotheses(thesis_setup1().downscaled(8), (400.0, 700.0))
        15
    """
    return _hypotheses(rig, *(float(z) for z in z_range_mm))


@functools.lru_cache(maxsize=16)
def _hypotheses(rig: BiPrismRig, z_min: float, z_max: float) -> int:
    """:func:`default_hypotheses`, once per rig and range (resolving a config asks for it again)."""
    from prismstereo.epipolar.sweep import SWEEP_PROBE_STRIDE, fit_sweep, sweep_coefficients, sweep_hypotheses

    fit = fit_sweep(rig, (z_min, z_max))
    f64, stride = torch.float64, SWEEP_PROBE_STRIDE
    uv = torch.stack(torch.meshgrid(torch.arange(0, rig.reference_width, stride, dtype=f64),
                                    torch.arange(0, rig.image_height, stride, dtype=f64), indexing="xy"), -1)
    return sweep_hypotheses(sweep_coefficients(fit, uv).permute(2, 0, 1, 3), stride=1)


def default_downsample(rig: BiPrismRig) -> int:
    """k = 2 (the pyramid, with ``full_band`` 2) when the reference half is at least 384 px on its shorter side,
    else 1 (coarse-to-fine at full resolution).

    Args:
        rig: the rig.

    Returns:
        The binning k of the model's ``downsample``.

    Example:
        >>> [default_downsample(thesis_setup1().downscaled(k)) for k in (1, 2)]
        [2, 1]
    """
    return 2 if min(rig.image_height, rig.reference_width) >= 384 else 1


def default_coarse_factor(num_hypotheses: int, height: int, width: int) -> int:
    """f = the largest power of two (<= 4) leaving >= 24 hypotheses and >= 32 rows and columns at the coarse
    level; 1 (a single full-resolution level) for small searches.

    Args:
        num_hypotheses: D of the level's image.
        height, width: the reference half's size (px) at that level.

    Returns:
        The coarse factor f.

    Example:
        >>> [default_coarse_factor(d, h, w) for d, h, w in ((368, 768, 512), (103, 768, 512), (40, 96, 64))]
        [4, 4, 1]
    """
    return _coarse_factor(num_hypotheses, height, width, 24)


def pyramid_coarse_factor(num_hypotheses: int, height: int, width: int) -> int:
    """The coarse factor of a pyramid's binned level: as :func:`default_coarse_factor`, leaving >= 12 hypotheses
    instead of 24, since its estimate only places the full-resolution band.

    Args:
        num_hypotheses: D of the binned image.
        height, width: the binned reference half's size (px).

    Returns:
        The coarse factor f.

    Example:
        >>> [pyramid_coarse_factor(d, 384, 256) for d in (52, 47, 222)], default_coarse_factor(52, 384, 256)
        ([4, 2, 4], 2)
    """
    return _coarse_factor(num_hypotheses, height, width, 12)


def _coarse_factor(num_hypotheses: int, height: int, width: int, least: int) -> int:
    """The largest power of two f <= 4 leaving >= ``least`` hypotheses and >= 32 rows and columns."""
    f = 1
    while f < 4 and num_hypotheses / (2 * f) >= least and min(height, width) / (2 * f) >= 32:
        f *= 2
    return f


def pyramid_band(coarse_factor: int) -> int:
    """Half width R of the binned level's band in a pyramid: ceil(3 f / 4) (f = 4 -> 3, f = 2 -> 2), against
    f + 1 for a level's own band, since its estimate only places the full-resolution band.

    Args:
        coarse_factor: the binned level's coarse factor f (> 1).

    Returns:
        R.

    Example:
        >>> [pyramid_band(f) for f in (2, 4)]
        [2, 3]
    """
    return math.ceil(3 * coarse_factor / 4)
