"""Maps of a binned grid brought to the full-resolution grid: what the models do with a level's result.

A level binned by f sees the sensor through f x f blocks: its pixel i covers full-resolution pixels f i ... f i +
f - 1, centred on f i + (f - 1) / 2 (:meth:`~prismstereo.geometry.rig.BiPrismRig.binned`). :func:`upsample` is the
one way back, shared by the classical model's block mode and pyramid, the temporal band on the binned frame and
the hybrid's learned stages: each pixel its block's value ('nearest') or an interpolation between block centres
('bilinear').
"""

from __future__ import annotations

from typing import Literal

import torch
import torch.nn.functional as F

from prismstereo.errors import check_option
from prismstereo.runtime import crop

__all__ = ["upsample"]


def upsample(t: torch.Tensor, factor: int, size: tuple[int, int], mode: Literal["nearest", "bilinear"] = "nearest",
             beyond: Literal["replicate", "zero"] = "replicate") -> torch.Tensor:
    """A level's (B, C, h, w) map at the ``factor`` times finer resolution of ``size`` (H, W): level pixel i covers
    pixels f i ... f i + f - 1 ('nearest'; 'bilinear' interpolates between the pixel centres, align_corners=False).
    A level binned by f may end short of the finer one (its size rounded down): the rows and columns beyond it
    repeat its last one (``beyond='replicate'``) or are 0 (``'zero'``); a level that reaches past it is cut.

    Args:
        t: (B, C, h, w) the binned map.
        factor: f >= 1.
        size: (H, W) of the finer grid.
        mode: 'nearest' or 'bilinear'.
        beyond: 'replicate' or 'zero'.

    Returns:
        (B, C, H, W).

    Raises:
        OptionError: an unknown ``mode`` or ``beyond``, listing the valid ones.

    Example:
        >>> upsample(torch.ones(1, 1, 2, 2), 2, (5, 5), beyond="zero")[0, 0, :, -1].tolist()
        [0.0, 0.0, 0.0, 0.0, 0.0]
    """
    check_option(mode, ("nearest", "bilinear"), "mode")
    check_option(beyond, ("replicate", "zero"), "beyond")
    corners = {} if mode == "nearest" else {"align_corners": False}
    t = F.interpolate(t, scale_factor=factor, mode=mode, **corners)
    h, w = size
    if t.shape[-2] < h or t.shape[-1] < w:
        pad = (0, max(0, w - t.shape[-1]), 0, max(0, h - t.shape[-2]))
        t = F.pad(t, pad, mode="replicate") if beyond == "replicate" else F.pad(t, pad)
    return crop(t, h, w)
