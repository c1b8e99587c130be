"""What a depth level knows from the optics alone, computed once per rig and range.

A :class:`~prismstereo.classical.level.DepthLevel` holds, besides its options, maps that depend only on its rig and
range: which pixels of each half see through the prism (thesis eq. 3.1-3.10 traced), the sweep's truncated power
series per reference pixel (eq. 4.1-4.10 done exactly, :mod:`~prismstereo.epipolar.series`) and each pixel's interval
of sweep coordinates whose sample is real (:func:`~prismstereo.epipolar.sweep_table.valid_interval`). Building them
costs seconds on a 1024 x 768 sensor, far more than a forward pass; tests, notebooks, benchmarks and applications
build several models of one rig and range (a pyramid's levels, option sets, exports, the hybrid's classical level and
exact stage). :func:`level_geometry` keeps the most recently used ones (:data:`KEPT`, :data:`KEPT_BYTES`; a hit is a
copy, bitwise what computing them again gives: the computation is deterministic), as
:func:`~prismstereo.epipolar.sweep.fit_sweep` keeps its fits.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import NamedTuple

import torch

from prismstereo.epipolar.series import sweep_series
from prismstereo.epipolar.sweep import SweepFit, sweep_coefficients
from prismstereo.epipolar.sweep_table import tabulate_sweep, valid_interval
from prismstereo.errors import OptionError
from prismstereo.geometry.optics import trace_pixels
from prismstereo.geometry.rig import BiPrismRig

__all__ = ["KEPT", "KEPT_BYTES", "LevelGeometry", "fine_coefficients", "level_geometry"]

KEPT = 8
"""Rig and range pairs whose maps are kept at most."""
KEPT_BYTES = 256 * 2**20
"""and the most memory they hold together (a 1024 x 768 rig's maps take 19 MB, a 1920 x 1080 one's 57 MB): the least
recently used go first."""

_CACHE: OrderedDict[tuple, LevelGeometry] = OrderedDict()
_LOCK = threading.Lock()


class LevelGeometry(NamedTuple):
    """A level's maps from the optics alone (:func:`level_geometry`).

    Attributes:
        reference_valid: (H, W_ref) bool, reference pixels whose ray sees through the left face.
        other_valid: (H, W_o) bool, other-half pixels whose ray sees through the right face.
        series: the sweep's truncated power series of every reference pixel, float32
            (:func:`~prismstereo.epipolar.series.sweep_series`).
        interval: (2, H, W_ref) float32 [s_lo, s_hi] of each reference pixel's real samples.
    """

    reference_valid: torch.Tensor
    other_valid: torch.Tensor
    series: torch.Tensor
    interval: torch.Tensor


def fine_coefficients(rig: BiPrismRig, fit: SweepFit) -> torch.Tensor:
    """(N, H, W_ref, 2) float64 sweep polynomials of every reference pixel of ``rig`` (full-sensor pixels).

    Example:
        >>> from prismstereo.epipolar.sweep import fit_sweep
        >>> rig = thesis_setup1().downscaled(8)
        >>> fine_coefficients(rig, fit_sweep(rig, (450.0, 900.0))).shape[1:]
        torch.Size([96, 64, 2])
    """
    uv = _pixels(0, rig.reference_width, rig.image_height)
    return sweep_coefficients(fit, uv).permute(2, 0, 1, 3).contiguous()


def _pixels(first: int, end: int, h: int) -> torch.Tensor:
    """(h, end - first, 2) float64 (u, v) of the columns first..end - 1 of every row."""
    f64 = torch.float64
    return torch.stack(torch.meshgrid(torch.arange(first, end, dtype=f64), torch.arange(h, dtype=f64),
                                      indexing="xy"), -1)


def level_geometry(rig: BiPrismRig, z_range: tuple[float, float], fit: SweepFit, split: int,
                   fine: torch.Tensor | None = None) -> LevelGeometry:
    """The maps of a level of ``rig`` over ``z_range`` (module docstring), from the cache when recently computed.

    Args:
        rig: the level's rig.
        z_range: (z_min, z_max) mm, the range ``fit`` was fitted over.
        fit: :func:`~prismstereo.epipolar.sweep.fit_sweep` of the rig and range.
        split: the other half's first full-sensor column.
        fine: :func:`fine_coefficients` of the rig and fit when the caller has them (a level with its own search
            needs them anyway), else computed on a miss.

    Returns:
        LevelGeometry.

    Raises:
        OptionError: a rig that is not a BiPrismRig.

    Example:
        >>> from prismstereo.epipolar.sweep import fit_sweep
        >>> rig = thesis_setup1().downscaled(8)
        >>> maps = level_geometry(rig, (450.0, 900.0), fit_sweep(rig, (450.0, 900.0)), rig.reference_width)
        >>> maps.interval.shape, maps.other_valid.shape
        (torch.Size([2, 96, 64]), torch.Size([96, 64]))
    """
    if not isinstance(rig, BiPrismRig):
        raise OptionError(f"rig must be a BiPrismRig, got {type(rig).__name__}")
    key = (repr(rig), tuple(float(z).hex() for z in z_range), int(split))
    with _LOCK:
        hit = _CACHE.get(key)
        if hit is not None:
            _CACHE.move_to_end(key)
    if hit is None:
        hit = _compute(rig, fit, split, fine_coefficients(rig, fit) if fine is None else fine)
        with _LOCK:
            _CACHE[key] = hit
            while len(_CACHE) > KEPT or (len(_CACHE) > 1 and sum(map(_bytes, _CACHE.values())) > KEPT_BYTES):
                _CACHE.popitem(last=False)
    return LevelGeometry(*(t.clone() for t in hit))


def _bytes(maps: LevelGeometry) -> int:
    return sum(t.numel() * t.element_size() for t in maps)


def _compute(rig: BiPrismRig, fit: SweepFit, split: int, fine: torch.Tensor) -> LevelGeometry:
    h, w_ref, w = rig.image_height, rig.reference_width, rig.image_width
    rays, rays_o = (trace_pixels(rig, _pixels(lo, hi, h).view(-1, 2)) for lo, hi in ((0, w_ref), (w_ref, w)))
    other_valid = (rays_o.valid & ~rays_o.left).view(h, w - w_ref)
    return LevelGeometry((rays.valid & rays.left).view(h, w_ref), other_valid, sweep_series(fine).float(),
                         valid_interval(tabulate_sweep(fine).float(), other_valid, split))
