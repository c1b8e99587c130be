"""How :class:`~prismstereo.model.PrismStereo` picks its defaults: the rules, as functions the model calls.

Each rule keeps one line of rationale; what was measured for each default and its alternatives (option by option,
with the benchmark commands) is in ``docs/design.md``, *How the model picks its defaults*, so that a change of
default starts from the numbers.
"""

from __future__ import annotations

import math

from prismstereo.geometry.rig import BiPrismRig

__all__ = ["default_coarse_factor", "default_downsample", "pyramid_band", "pyramid_coarse_factor"]


def default_downsample(rig: BiPrismRig) -> int:
    """k = 2 (the pyramid, with ``full_band`` 2) when the reference half is at least 384 px on its shorter side,
    else 1 (coarse-to-fine at full resolution); see ``downsample`` in the module docstring.

    Args:
        rig: the rig.

    Returns:
        The binning k of :class:`~prismstereo.model.PrismStereo`'s ``downsample``.

    Example:
        >>> [default_downsample(thesis_setup1().downscaled(k)) for k in (1, 2)]
        [2, 1]
    """
    return 2 if min(rig.image_height, rig.reference_width) >= 384 else 1


def default_coarse_factor(num_hypotheses: int, height: int, width: int) -> int:
    """f = the largest power of two (<= 4) leaving >= 24 hypotheses and >= 32 rows and columns at the coarse
    level; 1 (a single full-resolution level) for small searches. See ``coarse_factor`` in the module docstring.

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
    """The coarse factor of a pyramid's binned model: as :func:`default_coarse_factor`, leaving >= 12 hypotheses
    instead of 24, since its estimate only places the full-resolution band (``coarse_factor`` in the module
    docstring: the narrow range's binned model gets f = 4 instead of 2).

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
    """Half width R of the binned model's band in a pyramid: ceil(3 f / 4) (f = 4 -> 3, f = 2 -> 2), against
    f + 1 for a model's own band, since its estimate only places the full-resolution band (``band`` in the
    module docstring).

    Args:
        coarse_factor: the binned model's coarse factor f (> 1).

    Returns:
        R.

    Example:
        >>> [pyramid_band(f) for f in (2, 4)]
        [2, 3]
    """
    return math.ceil(3 * coarse_factor / 4)
