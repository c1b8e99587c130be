"""A learned-feature cost volume on the exact plane sweep of the bi-prism (thesis ch. 3-4).

Reference pixel (u, v) of the left half sees, at depth Z, the point on its ray that the right half images at
the exact ray-traced position m(u, v, s) (eq. 3.1-3.10 forward and backward; the virtual epipolar curve of
ch. 4, which eq. 4.1-4.10 approximate by a straight line). The sweep coordinate s in [-1, 1] is linear in 1/Z
(s = -1 at z_min, +1 at z_max), so D hypotheses uniform in s are uniform in inverse depth.

:func:`sweep_grid` evaluates the fitted sweep (:func:`~prismstereo.epipolar.sweep.fit_sweep`) of the rig seen
through ``scale`` x ``scale`` binning (the full-resolution fit at the blocks' centres) at every binned reference
pixel and hypothesis; :class:`PrismCostVolume` samples the right half of a feature map there and correlates it
with the reference half (GwcNet / IGEV-style group-wise correlation, or a PSMNet-style concatenation volume for
3-D convolutions). Both sample through :class:`~prismstereo.matching.sweep_sampler.SweepSampler`, built by
:func:`~prismstereo.matching.sweep_sampler.sweep_sampler`: the classical model's sweep searches do too, so the
library has one implementation of the plane sweep's sampling.

Validity (the classical model's rule, :func:`~prismstereo.matching.sweep_cost.warp_slices`): a sample is valid
where the reference pixel's own ray (through its block's centre) enters the left face, the sample lies between the
first and last pixel centres of the right half (every bilinear tap inside it, 1e-3 px slack), and every tap with
non-zero weight is a binned right-half pixel whose whole block of sensor pixels sees through the right face.
"""

from __future__ import annotations

from typing import Literal, NamedTuple

import torch
from torch import nn

from prismstereo.epipolar.row_rectify import level_coverage
from prismstereo.epipolar.sweep import fit_sweep, positions_at, sweep_coefficients, sweep_to_depth
from prismstereo.errors import OptionError, RigError, ShapeError, check_int, check_option, check_shape
from prismstereo.geometry.optics import check_rig_images, trace_pixels
from prismstereo.geometry.parameters import RigParameters
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.matching.sweep_sampler import SweepSampler, block_centres, sweep_sampler

__all__ = ["MODES", "Mode", "PrismCostVolume", "SweepGrid", "sweep_grid"]

Mode = Literal["correlation", "concat"]
MODES: tuple[str, ...] = ("correlation", "concat")


class SweepGrid(NamedTuple):
    """The exact sweep of the binned reference half, ready for ``grid_sample``.

    Attributes:
        grid: (D, h, w_ref, 2) sample positions normalised for ``grid_sample`` (align_corners=False) on the
            *right half* of the binned feature map, columns w_ref .. W - 1 (the convention of
            :func:`~prismstereo.epipolar.grids.normalise_right_grid`).
        valid: (D, h, w_ref) bool, where the hypothesis samples the right half (see the module docstring).
        depths: (D,) hypotheses (mm), uniform in 1/Z from z_min to z_max.
        uv: (D, h, w_ref, 2) the same positions in binned full-sensor pixels (u, v).
    """

    grid: torch.Tensor
    valid: torch.Tensor
    depths: torch.Tensor
    uv: torch.Tensor


def _binned_parameters(p: RigParameters, scale: int) -> RigParameters:
    """:meth:`BiPrismRig.binned` on tensors (differentiable): pixels ``scale`` times larger, principal point of
    the block grid, c_binned = (c - (scale - 1) / 2) / scale."""
    shift = (scale - 1) / 2
    return p._replace(pixel_size=p.pixel_size * scale, cx=(p.cx - shift) / scale, cy=(p.cy - shift) / scale,
                      width=p.width // scale, height=p.height // scale)


def _binned_size(rig: BiPrismRig | RigParameters, scale: int) -> tuple[int, int, int]:
    """(h, W_b, w_ref) of the rig seen through ``scale`` x ``scale`` binning; checks that both halves exist."""
    if isinstance(rig, BiPrismRig):
        if rig.image_width // scale < 2 or rig.image_height // scale < 1:
            raise OptionError(f"scale {scale} leaves no binned image of the {rig.image_width}x{rig.image_height} "
                              "sensor")
        binned = rig.binned(scale)
        height, width = binned.image_height, binned.image_width
    elif isinstance(rig, RigParameters):
        binned = _binned_parameters(rig, scale)
        height, width = int(binned.height), int(binned.width)
    else:
        raise RigError(f"rig must be a BiPrismRig or RigParameters, got {type(rig).__name__}")
    w_ref = int(binned.reference_width)
    if not 0 < w_ref < width:
        raise RigError(f"the binned sensor ({width} columns, split at {w_ref}) has an empty half at scale {scale}")
    return height, width, w_ref


class _Built(NamedTuple):
    sampler: SweepSampler
    valid: torch.Tensor
    depths: torch.Tensor
    coefficients: torch.Tensor  # (N, h, w_ref, 2) full-sensor pixels at the block centres


def _build(rig: BiPrismRig | RigParameters, z_range_mm: tuple[float, float] | torch.Tensor, num_hypotheses: int,
           scale: int) -> _Built:
    """The binned level's :class:`~prismstereo.matching.sweep_sampler.SweepSampler` (the classical model's
    :func:`~prismstereo.matching.sweep_sampler.sweep_sampler`) and the volume's validity."""
    h, width, w_ref = _binned_size(rig, scale)
    fit = fit_sweep(rig, z_range_mm)
    like = fit.coefficients
    centres = block_centres(h, w_ref, scale, like)
    coefficients = sweep_coefficients(fit, centres).permute(2, 0, 1, 3)
    with torch.no_grad():
        frozen = rig if isinstance(rig, BiPrismRig) else rig.detach()
        rays = trace_pixels(frozen, centres.detach())
        u_o = torch.arange(w_ref * scale, width * scale, dtype=like.dtype, device=like.device)
        v = torch.arange(h * scale, dtype=like.dtype, device=like.device)
        rays_o = trace_pixels(frozen, torch.stack(torch.meshgrid(u_o, v, indexing="xy"), dim=-1))
        other_valid = level_coverage(rays_o.valid & ~rays_o.left, scale) > 0.999  # every pixel of the block
    sampler = sweep_sampler(fit, num_hypotheses, factor=scale, reference_size=(h, w_ref), other_start=w_ref * scale,
                            other_valid=other_valid, coefficients=coefficients)
    valid = sampler.valid & (rays.valid & rays.left)
    s = torch.linspace(-1.0, 1.0, num_hypotheses, dtype=like.dtype, device=like.device)
    return _Built(sampler, valid, sweep_to_depth(s, fit.z_range), coefficients)


def sweep_grid(
    rig: BiPrismRig | RigParameters,
    z_range_mm: tuple[float, float] | torch.Tensor,
    num_hypotheses: int,
    scale: int = 1,
) -> SweepGrid:
    """The exact plane-sweep grid of the rig seen through ``scale`` x ``scale`` binning.

    The binned reference pixels (u, v), u in [0, w_ref), v in [0, h), pixel centres at integers, at D sweep
    coordinates s_i = -1 + 2 i / (D - 1): positions m(u, v, s_i) of the Chebyshev fit of the exact projections
    (:func:`~prismstereo.epipolar.sweep.fit_sweep` of the full-resolution rig at the blocks' centres, within
    1e-3 px of them), depths Z_i = 1 / (1/z_min + (s_i + 1) / 2 (1/z_max - 1/z_min)). The grid is the one
    :class:`PrismCostVolume` and the classical model's sweep searches sample
    (:func:`~prismstereo.matching.sweep_sampler.sweep_sampler`).

    Args:
        rig: the full-resolution rig. A :class:`BiPrismRig` is computed in float64; :class:`RigParameters` in
            their dtype, differentiably (``grid``, ``uv`` and ``depths`` carry gradients to them; ``valid`` is a
            mask and does not).
        z_range_mm: (z_min, z_max), beyond the prism's back plane, increasing.
        num_hypotheses: D >= 2.
        scale: the binning factor (>= 1): the grid addresses the (H // scale, W // scale) feature map.

    Returns:
        SweepGrid.

    Raises:
        OptionError: bad ``num_hypotheses`` or ``scale``. RigError: bad rig or range, or a binned half without
            columns.

    Example:
        >>> g = sweep_grid(thesis_setup1().downscaled(8), (400.0, 1000.0), 16, scale=2)
        >>> g.grid.shape, g.valid.shape, g.depths.shape
        (torch.Size([16, 48, 32, 2]), torch.Size([16, 48, 32]), torch.Size([16]))
    """
    check_int(num_hypotheses, "num_hypotheses", 2)
    check_int(scale, "scale", 1)
    built = _build(rig, z_range_mm, num_hypotheses, scale)
    c = built.coefficients
    s = torch.linspace(-1.0, 1.0, num_hypotheses, dtype=c.dtype, device=c.device)
    uv = (positions_at(built.coefficients, s) - (scale - 1) / 2) / scale  # binned full-sensor pixels
    return SweepGrid(built.sampler.grid(), built.valid, built.depths, uv)


class PrismCostVolume(nn.Module):
    """Correlate the two half-images of a feature map along each reference pixel's exact sweep.

    The features (B, C, h, W_b) are computed on the whole capture (both halves side by side, as recorded) at
    1/``scale`` resolution: (h, W_b) = (H // scale, W // scale), the binned rig's sensor
    (:meth:`~prismstereo.geometry.rig.BiPrismRig.binned`). The layer splits them at the binned apex column
    w_ref (:attr:`~prismstereo.geometry.rig.BiPrismRig.reference_width`: reference = left half, columns
    [0, w_ref)), samples the right half bilinearly at the D exact sweep positions of every reference pixel
    (one ``grid_sample``, border padding, :func:`~prismstereo.matching.sweep_cost.sample_slices`) and compares:

    * ``'correlation'``: C_g(d, v, u) = (1 / (C/G)) sum_{c in group g} f_ref[c](v, u) f_right[c](m(u, v, s_d)),
      the channel mean within each of G = ``groups`` groups. Output (B, D, h, w_ref) when ``groups`` is 1,
      (B, G, D, h, w_ref) when it is > 1 (the group axis only exists when there are several).
    * ``'concat'``: reference features repeated over D, then the sampled features: (B, 2 C, D, h, w_ref)
      (``groups`` must be 1).

    Entries where the hypothesis does not sample the right half (:attr:`valid` False; rule in the module
    docstring) are 0: the correlation, and in ``'concat'`` both halves of the entry (as PSMNet zeroes the
    disparities beyond the image). Pass :attr:`valid` to :func:`~prismstereo.nn.regression.depth_regression`.

    The sampling is the classical model's (:class:`~prismstereo.matching.sweep_sampler.SweepSampler`, the per-pixel
    sweep polynomials as a buffer, evaluated at the D hypotheses in each forward; it moves with ``.to()``, the
    volume takes the features' dtype).
    Gradients reach the features. With ``rig`` given as :class:`~prismstereo.geometry.parameters.RigParameters`
    whose tensors require grad (e.g. ``rig.parameters(dtype=torch.float64, requires_grad=True)``) the grid is
    recomputed from them in every forward (a sweep fit, slow next to the sampling), so gradients also reach the rig
    parameters (self-calibration through a network); :attr:`valid` is then updated each forward (a mask,
    without gradients) and the sensor size and split must stay those of construction. The fit runs in the
    parameters' dtype (use float64) and is cast to the features' dtype.

    Exports to ONNX (opset >= 16 for GridSample; static spatial sizes, any batch) with the polynomials and mask as
    constants, as :func:`~prismstereo.export.onnx.export_onnx` exports the classical model.

    Attributes:
        sampler: the :class:`~prismstereo.matching.sweep_sampler.SweepSampler` of the binned level.
        grid: (D, h, w_ref, 2) its positions, :attr:`SweepGrid.grid` (normalised on the right half of the features).
        valid: (D, h, w_ref) bool, where the hypothesis samples the right half (the sampler's mask).
        depths: (D,) buffer, hypotheses (mm), uniform in 1/Z.
        height, width, reference_width: h, W_b and w_ref of the binned sensor.

    Args:
        rig: the full-resolution rig (:class:`~prismstereo.geometry.rig.BiPrismRig` or ``RigParameters``). A
            ``BiPrismRig``'s geometry is checked first (:func:`~prismstereo.geometry.optics.check_rig_images`);
            ``RigParameters`` (tensors, e.g. being optimised) are taken as they are.
        z_range_mm: (z_min, z_max) mm, beyond the prism's back plane.
        num_hypotheses: D >= 2, uniform in 1/Z.
        scale: the features' downsampling relative to the sensor (>= 1).
        groups: G >= 1 correlation groups (C must be a multiple of G).
        mode: ``'correlation'`` or ``'concat'``.

    Raises:
        OptionError: unknown ``mode``, bad ``num_hypotheses``, ``scale`` or ``groups``. RigError: bad rig / range.

    Example:
        >>> volume = PrismCostVolume(thesis_setup1().downscaled(4), (400.0, 1000.0), num_hypotheses=8, scale=4)
        >>> cost = volume(torch.rand(2, 16, 48, 64))
        >>> cost.shape, volume.depths.shape, volume.valid.shape
        (torch.Size([2, 8, 48, 32]), torch.Size([8]), torch.Size([8, 48, 32]))
    """

    depths: torch.Tensor

    def __init__(
        self,
        rig: BiPrismRig | RigParameters,
        z_range_mm: tuple[float, float],
        num_hypotheses: int = 64,
        scale: int = 4,
        *,
        groups: int = 1,
        mode: Mode = "correlation",
    ) -> None:
        super().__init__()
        if isinstance(rig, BiPrismRig):
            check_rig_images(rig)
        self.mode = check_option(mode, MODES, "mode")
        self.groups = check_int(groups, "groups", 1)
        if mode == "concat" and groups != 1:
            raise OptionError(f"groups must be 1 with mode 'concat', got {groups}")
        self.scale = check_int(scale, "scale", 1)
        self.num_hypotheses = check_int(num_hypotheses, "num_hypotheses", 2)
        self.z_range_mm = tuple(float(z) for z in z_range_mm)
        self.rig = rig
        self.rig_gradients = isinstance(rig, RigParameters) and any(
            v.requires_grad for v in rig if isinstance(v, torch.Tensor))
        frozen = rig.detach() if isinstance(rig, RigParameters) else rig
        built = _build(frozen, self.z_range_mm, num_hypotheses, scale)
        self.height, self.width, self.reference_width = _binned_size(frozen, scale)
        dtype = torch.get_default_dtype()
        self.sampler = SweepSampler(built.sampler.coefficients.to(dtype), num_hypotheses, valid=built.valid)
        self.register_buffer("depths", built.depths.to(dtype))

    @property
    def valid(self) -> torch.Tensor:
        """(D, h, w_ref) bool: where the hypothesis samples the right half (see the module docstring)."""
        return self.sampler.valid

    @property
    def grid(self) -> torch.Tensor:
        """(D, h, w_ref, 2) the sample positions, normalised on the right half of the features
        (:attr:`SweepGrid.grid`), in the buffers' dtype."""
        return self.sampler.grid()

    def extra_repr(self) -> str:
        return (f"z_range_mm={self.z_range_mm}, num_hypotheses={self.num_hypotheses}, scale={self.scale}, "
                f"groups={self.groups}, mode={self.mode!r}, rig_gradients={self.rig_gradients}")

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """The cost volume of ``features`` (B, C, h, W_b) of the whole capture at 1/scale resolution.

        Returns:
            (B, D, h, w_ref) (correlation, one group), (B, G, D, h, w_ref) (correlation, G > 1 groups) or
            (B, 2 C, D, h, w_ref) (concat); 0 where not :attr:`valid`.

        Raises:
            ShapeError: features not (B, C, h, W_b) of the binned sensor, or C not a multiple of ``groups``.
        """
        check_shape(features, ["B", "C", "H", "W"], "features")
        if tuple(features.shape[-2:]) != (self.height, self.width):
            raise ShapeError(f"features must be (B, C, {self.height}, {self.width}) (the sensor binned by "
                             f"{self.scale}), got {tuple(features.shape)}")
        channels = features.shape[1]
        if channels % self.groups:
            raise ShapeError(f"features have {channels} channels, not a multiple of groups={self.groups}")
        sampler, grid = self.sampler, None
        if self.rig_gradients:  # the grid recomputed from the rig, differentiably; the mask updated (no gradients)
            built = _build(self.rig, self.z_range_mm, self.num_hypotheses, self.scale)
            if tuple(built.valid.shape[1:]) != (self.height, self.reference_width):
                raise RigError(f"the rig's split moved: reference half {tuple(built.valid.shape[1:])}, built for "
                               f"{(self.height, self.reference_width)}")
            self.sampler.valid = built.valid.to(device=features.device)
            grid = built.sampler.grid()
        reference = features[..., :self.reference_width]
        sampled = sampler(features[..., self.reference_width:], grid).image  # (B, C, D, h, w_ref)
        mask = sampler.valid.to(features.dtype)  # a product, not a Where: one multi-threaded Mul in onnxruntime
        if self.mode == "concat":
            d = sampled.shape[2]
            return torch.cat([reference.unsqueeze(2).expand(-1, -1, d, -1, -1), sampled], 1) * mask
        product = reference.unsqueeze(2) * sampled
        if self.groups == 1:
            return product.mean(1) * mask
        grouped = product.reshape(-1, self.groups, channels // self.groups, *product.shape[2:])  # batch: dynamic
        return grouped.mean(2) * mask
