"""Pixels a capture cannot vouch for: NaN or infinite values (a dead pixel, a masked region, a corrupted frame).

Bad pixels are data, not crashes. A model takes its capture through :class:`BadPixels`, which replaces every
non-finite value by 0 (so no NaN reaches a window sum, an index or a gradient) and marks the reference pixels the
bad ones can reach: those whose own window touches one, and those whose exact sweep (eq. 3.1-3.10 traced over the
model's depth range, the curve of thesis ch. 4) passes within a window of one in the other half. The model's
result is then invalid with confidence 0 there (:func:`discard`); every other pixel is computed as usual. The mask
is plain arithmetic (pooling and one gather of constant indices), so the exported graph marks the same pixels.

Both tests run on blocks (:class:`BadPixels`), so the mask costs one pass over the capture and a sweep sampled at
1/512 of a full-resolution cost volume's points. It is conservative: the blocks' spread, the sampling step along the
sweep and the rounding to blocks are added to the window, so a pixel it keeps cannot have touched a bad one, while a
few pixels at the edge of a marked band are marked without need.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.depth.result import DepthResult
from prismstereo.epipolar.sweep import fit_sweep, positions_at, sweep_coefficients, sweep_hypotheses
from prismstereo.errors import ImageValueError, ShapeError, check_int, check_shape
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.matching.sweep_sampler import block_centres
from prismstereo.runtime import box_max, tracing

__all__ = ["BAD_PIXEL_REACH", "BLOCK", "VALUE_TOLERANCE", "BadPixels", "Screened", "discard"]

BLOCK = 4
"""The block size (px) of :class:`BadPixels`' tests (its sweep test: blocks of twice this)."""
VALUE_TOLERANCE = 1 / 16
"""How far outside [0, 1] a capture's values may be (a resampling filter's overshoot) before it is refused."""
BAD_PIXEL_REACH = 4
"""The reach of a model's window around a pixel, in pixels of its matching grid (a model on k x k-binned pixels
screens that grid, or passes k times this as :class:`BadPixels`' ``radius``): 4 is half of a 9 x 9 window, the
default 5 x 5 ZNCC window with a margin. A bad pixel also moves the coarse placement and the smoothing of pixels
farther away; those keep the depth they would have had with any other value there (a test measures their share of
wrong depths unchanged)."""


class Screened(NamedTuple):
    """A capture screened by :class:`BadPixels`.

    Attributes:
        image: (B, C, H, W) the capture with every non-finite value replaced by 0.
        touched: (B, 1, H, W_ref) bool, the reference pixels whose window or sweep touches a non-finite pixel.
    """

    image: torch.Tensor
    touched: torch.Tensor


class BadPixels(nn.Module):
    """The reference pixels that non-finite pixels of a capture reach, through their windows or their sweeps.

    Both tests run on blocks: the capture's bad pixels are max-pooled once to 4 x 4 blocks (:data:`BLOCK`); a
    reference block is touched when a bad block lies within ``radius`` of it, or when the sweeps of its 8 x 8 block
    (their centre's, sampled every 8 px, against the other half's bad 8 x 8 blocks dilated by the spread of a block's
    sweeps, the sampling step and the window) pass one. Conservative by up to a block: a kept pixel cannot have
    touched a bad one.

    Args:
        rig: the sensor's rig.
        z_range: (z_min, z_max) mm, the model's searched range (the sweep's extent).
        radius: the model's reach around a pixel (px, full sensor): a bad pixel within ``radius`` of a pixel, or of
            any point of its sweep, marks it.

    Raises:
        OptionError: a negative ``radius``.

    Example:
        >>> rig = thesis_setup1().downscaled(16)
        >>> image = torch.rand(1, 1, 48, 64); image[..., 20, 40] = float("nan")
        >>> screened = BadPixels(rig, (400.0, 700.0), radius=2)(image)
        >>> bool(screened.image.isfinite().all()), screened.touched.shape, bool(screened.touched[0, 0, 20].any())
        (True, torch.Size([1, 1, 48, 32]), True)
    """

    def __init__(self, rig: BiPrismRig, z_range: tuple[float, float], *, radius: int = BAD_PIXEL_REACH) -> None:
        super().__init__()
        check_int(radius, "radius", 0)
        self.rig, self.z_range = rig, (float(z_range[0]), float(z_range[1]))
        self.size, self.radius = (rig.image_height, rig.image_width, rig.reference_width), radius
        # in blocks: the window, half a block of spread of the sweeps within a block, half a sampling step and the
        # rounding of a position to its block (sweep test); the window (own test)
        self.margin = math.ceil((radius + 1.5 * 2 * BLOCK) / (2 * BLOCK))
        self.own_margin = math.ceil(radius / BLOCK)
        self.register_buffer("anchor", torch.zeros(0), persistent=False)  # where the model is (its device)
        self._index: torch.Tensor | None = None  # the sweeps' blocks, made when first needed
        self.steps = 0

    def _sweep_index(self, like: torch.Tensor) -> torch.Tensor:
        """(hc S wc,) the 8 x 8 block of the full sensor (row-major; ``hb wb``: off the sensor) holding each 8 x 8
        reference block's sweep at S steps <= 8 px apart; computed on first use (a model without bad pixels never
        needs it). A gather of these constants is the sweep test's sampling (faster than ``grid_sample``)."""
        if self._index is None:
            (h, w, w_ref), f = self.size, 2 * BLOCK
            hc, wc, hb, wb = math.ceil(h / f), math.ceil(w_ref / f), math.ceil(h / f), math.ceil(w / f)
            centres = block_centres(hc, wc, f, torch.zeros((), dtype=torch.float64))
            coefficients = sweep_coefficients(fit_sweep(self.rig, self.z_range), centres).permute(2, 0, 1, 3)
            self.steps = steps = sweep_hypotheses(coefficients, max_step_px=f, stride=1)
            uv = positions_at(coefficients, torch.linspace(-1.0, 1.0, steps, dtype=torch.float64))  # (S, hc, wc, 2)
            col, row = (torch.floor((uv[..., k] + 0.5) / f).long() for k in (0, 1))
            inside = (col >= 0) & (col < wb) & (row >= 0) & (row < hb)
            index = torch.where(inside, row * wb + col, torch.full_like(col, hb * wb))
            self._index = index.permute(1, 0, 2).reshape(-1)  # (hc, S, wc) flattened
        return self._index.to(like.device)

    def _touched(self, blocks: torch.Tensor) -> torch.Tensor:
        """(B, 1, H, W_ref) touched reference pixels of the 4 x 4 bad blocks (B, 1, ceil(H / 4), ceil(W / 4))."""
        h, _, w_ref = self.size
        q, m = BLOCK, self.own_margin
        ref = math.ceil(w_ref / q)
        own = blocks[..., :ref]
        if m:
            own = box_max(own, 2 * m + 1)
        # a sweep samples the other half only (beyond it the polynomials continue where no real ray goes)
        split = w_ref // q
        other = torch.cat([torch.zeros_like(blocks[..., :split]), blocks[..., split:]], -1)
        other = F.max_pool2d(other, 2, 2, ceil_mode=bool(other.shape[-2] % 2 or other.shape[-1] % 2))
        other = box_max(other, 2 * self.margin + 1)
        index = self._sweep_index(blocks)
        flat = torch.cat([other.flatten(1), torch.zeros_like(other.flatten(1)[:, :1])], 1)  # a last 0: off the sensor
        hc = math.ceil(h / (2 * q))
        hits = flat[:, index].view(blocks.shape[0], 1, hc, self.steps, -1).amax(dim=3)  # (B, 1, hc, wc)
        hits = hits.repeat_interleave(2, dim=2).repeat_interleave(2, dim=3)[..., :own.shape[-2], :ref]
        full = F.interpolate(own + hits, scale_factor=q, mode="nearest")  # each block's pixels
        return full[..., :h, :w_ref] > 0

    def forward(self, image: torch.Tensor) -> Screened:
        """Screen captures ``image`` (B, C, H, W).

        Returns:
            :class:`Screened`: the finite image and the (B, 1, H, W_ref) touched reference pixels.

        Raises:
            ShapeError: an image that is not (B, C, H, W) of the rig's sensor, or on another device than the model.
            ImageValueError: finite values outside [0, 1] (beyond :data:`VALUE_TOLERANCE`), such as 8-bit levels
                as floats (checked in eager mode).
        """
        check_shape(image, ["B", "C", "H", "W"], "image")
        h, w, w_ref = self.size
        if tuple(image.shape[-2:]) != (h, w):
            raise ShapeError(f"image is {image.shape[-1]}x{image.shape[-2]} px but the rig's sensor is {w}x{h}")
        if image.device != self.anchor.device:
            where = "the meta device (a tensor without data)" if image.is_meta else str(image.device)
            raise ShapeError(f"image is on {where} but the model is on {self.anchor.device}: a capture with data on "
                             f"the model's device (model.to(device))")
        probe = image * 0.0  # 0 where finite, NaN where not (cheaper than isfinite)
        clean = torch.where(probe != probe, 0.0, image)
        # a block's sum is NaN when one of its values is: the bad blocks from one reduced pass
        # ceil_mode only where 4 does not divide the sensor (onnxruntime's pooling is slower with it)
        blocks = F.avg_pool2d(probe.sum(1, keepdim=True) if image.shape[1] > 1 else probe, BLOCK, BLOCK,
                              ceil_mode=bool(h % BLOCK or w % BLOCK))
        blocks = (blocks != blocks).to(clean.dtype)
        if not tracing():
            _check_values(clean)
        if not tracing() and not bool(blocks.any()):  # eager and clean: nothing to mark
            return Screened(clean, torch.zeros_like(clean[:, :1, :, :w_ref], dtype=torch.bool))
        return Screened(clean, self._touched(blocks))


def _check_values(image: torch.Tensor) -> None:
    """Raise :class:`~prismstereo.errors.ImageValueError` unless the finite values of ``image`` are in [0, 1]."""
    lo, hi = (float(v) for v in image.detach().aminmax())
    if lo < -VALUE_TOLERANCE or hi > 1.0 + VALUE_TOLERANCE:
        hint = ": 8-bit levels? divide by 255 (16-bit: 65535)" if hi > 1.0 + VALUE_TOLERANCE else ""
        raise ImageValueError(f"image values must be in [0, 1], got {lo:.4g} to {hi:.4g}{hint}")


def discard(result: DepthResult, touched: torch.Tensor) -> DepthResult:
    """``result`` with the ``touched`` pixels (B, 1, H, W_ref) invalid and of confidence 0 (no depth, also in a
    dense output).

    Example:
        >>> r = DepthResult(*(torch.ones(1, 1, 2, 2) for _ in range(3)), torch.zeros(1, 1, 2, 2),
        ...                 torch.zeros(1, 2, 2, 2))
        >>> discard(r._replace(valid=r.valid > 0), torch.tensor([[[[True, False], [False, False]]]])).confidence
        tensor([[[[0., 1.],
                  [1., 1.]]]])
    """
    keep = ~touched
    return result._replace(valid=result.valid & keep, confidence=result.confidence * keep.to(result.confidence))
