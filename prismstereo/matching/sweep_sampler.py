"""The plane sweep's sampling: the other half-image on every reference pixel's exact sweep, at D hypotheses.

Reference pixel (u, v) sees, at sweep coordinate s (linear in 1/Z, thesis ch. 3-4), the point that the other
half images at m(u, v, s), the exact ray-traced position (eq. 3.1-3.10 forward and backward; the virtual epipolar
curve that eq. 4.1-4.10 approximate by a line), fitted once per rig (:func:`~prismstereo.epipolar.sweep.fit_sweep`).
A :class:`SweepSampler` holds each pixel's polynomial in s of m, already in ``grid_sample`` units of the other
half, and samples that half at D hypotheses uniform in s with one ``grid_sample`` call
(:func:`~prismstereo.matching.sweep_cost.warp_slices`).

It is the one implementation of the plane sweep's sampling in the library: the classical model's searches
(:class:`~prismstereo.matching.search.SweepSearch`: a coarse level of f x f blocks, or a single full-resolution
level) and the learned-feature volume :class:`~prismstereo.nn.PrismCostVolume` both sample through it, and
:func:`sweep_sampler` builds it for either. A level of f x f blocks is the rig seen through f x f binning: its
pixel i is centred on full-resolution pixel f i + (f - 1) / 2, so its sweep is the full-resolution fit evaluated at
the block centres and divided by f.

Validity of a sample (:func:`~prismstereo.matching.sweep_cost.warp_slices`): between the first and last pixel
centres of the other half (1e-3 px slack), and every bilinear tap with non-zero weight a level pixel whose block
sees through the prism entirely. It is computed once when the level's geometry fixes it (``precompute``), or in
every call from the other half's mask (a full-resolution level of many hypotheses, whose (D, H, W) mask would be
large).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from prismstereo.epipolar.sweep import SweepFit, positions_at, sweep_coefficients
from prismstereo.errors import OptionError, ShapeError, check_int
from prismstereo.matching.cost import Warped
from prismstereo.matching.sweep_cost import sample_slices, warp_slices

__all__ = ["SweepSampler", "block_centres", "sweep_sampler"]


class SweepSampler(nn.Module):
    """Samples of the other half on each reference pixel's exact sweep at D hypotheses s_i = -1 + 2 i / (D - 1).

    Args:
        coefficients: (N, h, w, 2) per-pixel Chebyshev coefficients in s of the sample positions, normalised for
            ``grid_sample`` (align_corners=False) on the level's other half.
        num_hypotheses: D >= 2.
        valid: (D, h, w) bool, the samples' validity when fixed in advance; or None.
        other_valid: (h_o, w_o) bool, the other half's real pixels, checked in every call when ``valid`` is None.

    Attributes:
        coefficients, valid, other_valid: buffers (they move with ``.to()``; the samples take the image's dtype).

    Raises:
        OptionError: neither or both of ``valid`` and ``other_valid``, or D < 2. ShapeError: shapes that differ.

    Example:
        >>> sampler = SweepSampler(torch.zeros(3, 8, 6, 2), 4, other_valid=torch.ones(8, 6, dtype=torch.bool))
        >>> warped = sampler(torch.rand(2, 1, 8, 6))
        >>> warped.image.shape, warped.valid.shape
        (torch.Size([2, 1, 4, 8, 6]), torch.Size([2, 4, 8, 6]))
    """

    valid: torch.Tensor | None
    other_valid: torch.Tensor | None

    def __init__(self, coefficients: torch.Tensor, num_hypotheses: int, *, valid: torch.Tensor | None = None,
                 other_valid: torch.Tensor | None = None) -> None:
        super().__init__()
        if (valid is None) == (other_valid is None):
            raise OptionError("a sweep sampler needs either its samples' validity or the other half's mask")
        check_int(num_hypotheses, "num_hypotheses", 2)
        if coefficients.dim() != 4 or coefficients.shape[-1] != 2:
            raise ShapeError(f"coefficients must be (N, h, w, 2), got {tuple(coefficients.shape)}")
        if valid is not None and tuple(valid.shape) != (num_hypotheses, *coefficients.shape[1:3]):
            raise ShapeError(f"valid must be ({num_hypotheses}, {coefficients.shape[1]}, {coefficients.shape[2]}), "
                             f"got {tuple(valid.shape)}")
        self.num_hypotheses = num_hypotheses
        self.register_buffer("coefficients", coefficients)
        self.register_buffer("valid", valid)
        self.register_buffer("other_valid", other_valid)

    def extra_repr(self) -> str:
        return f"num_hypotheses={self.num_hypotheses}, precomputed_valid={self.valid is not None}"

    def grid(self, like: torch.Tensor | None = None) -> torch.Tensor:
        """The (D, h, w, 2) sample positions in ``grid_sample`` units (dtype and device of ``like``, default the
        coefficients')."""
        coefficients = self.coefficients if like is None else self.coefficients.to(like)
        s = torch.linspace(-1.0, 1.0, self.num_hypotheses, dtype=coefficients.dtype, device=coefficients.device)
        return positions_at(coefficients, s)

    def forward(self, other: torch.Tensor, grid: torch.Tensor | None = None) -> Warped:
        """The other half ``other`` (B, C, h_o, w_o) on the sweep: :class:`~prismstereo.matching.cost.Warped`
        with image (B, C, D, h, w) and valid (B, D, h, w). ``grid`` replaces :meth:`grid`'s positions (a grid
        recomputed differentiably from the rig); its validity must then be the sampler's."""
        grid = (self.grid(other) if grid is None else grid.to(other)).unsqueeze(0)
        if self.valid is None:
            return warp_slices(other, grid, self.other_valid, shared=True)
        b = other.shape[0]
        return Warped(sample_slices(other, grid, shared=True), self.valid.unsqueeze(0).expand(b, -1, -1, -1))


def block_centres(height: int, width: int, factor: int, like: torch.Tensor) -> torch.Tensor:
    """Full-resolution (u, v) of the centres of ``height`` x ``width`` blocks of ``factor`` x ``factor`` pixels,
    (height, width, 2) in ``like``'s dtype: block (i, j) is centred on (f j + (f - 1) / 2, f i + (f - 1) / 2).

    Example:
        >>> block_centres(1, 2, 4, torch.zeros(())).tolist()
        [[[1.5, 1.5], [5.5, 1.5]]]
    """
    u = (torch.arange(width, dtype=like.dtype, device=like.device) + 0.5) * factor - 0.5
    v = (torch.arange(height, dtype=like.dtype, device=like.device) + 0.5) * factor - 0.5
    return torch.stack(torch.meshgrid(u, v, indexing="xy"), -1)


def sweep_sampler(
    fit: SweepFit,
    num_hypotheses: int,
    *,
    factor: int = 1,
    reference_size: tuple[int, int] | None = None,
    other_start: int,
    other_valid: torch.Tensor,
    precompute: bool = True,
    dtype: torch.dtype | None = None,
    coefficients: torch.Tensor | None = None,
) -> SweepSampler:
    """The :class:`SweepSampler` of a level of ``factor`` x ``factor`` blocks (1: full resolution).

    The per-pixel polynomials are the full-resolution fit at the level's block centres (:func:`block_centres`),
    mapped to ``grid_sample`` units of the level's other half: a level pixel x_l = (x - start - (f - 1) / 2) / f
    normalised by its size, i.e. (2 (x - start) + 1) / (f w_o) - 1 and (2 y + 1) / (f h_o) - 1 (affine in the
    coefficients: only T_0's gets the offset).

    Args:
        fit: the rig's full-resolution sweep fit (:func:`~prismstereo.epipolar.sweep.fit_sweep`; its dtype, with
            gradients if it has them).
        num_hypotheses: D >= 2.
        factor: f >= 1.
        reference_size: (h, w) of the level's reference half; default: the full-resolution reference half in
            blocks, (ceil(H / f), ceil(W_ref / f)).
        other_start: the other half's first column (full-resolution pixels).
        other_valid: (h_o, w_o) bool, the level's other-half pixels that are real (their size is the level's other
            half).
        precompute: fix the samples' validity now (a (D, h, w) mask) instead of checking ``other_valid`` in every
            call.
        dtype: of the sampler's coefficients (default: the fit's).
        coefficients: (N, h, w, 2) the polynomials at the block centres in full-resolution pixels, when already
            computed (:func:`~prismstereo.epipolar.sweep.sweep_coefficients`, permuted); else computed here.

    Returns:
        SweepSampler.

    Raises:
        OptionError: a factor < 1. ShapeError: ``coefficients`` that do not match the reference size.

    Example:
        >>> from prismstereo.epipolar.sweep import fit_sweep
        >>> rig = thesis_setup1().downscaled(8); fit = fit_sweep(rig, (400.0, 700.0))
        >>> sampler = sweep_sampler(fit, 6, factor=2, other_start=64, other_valid=torch.ones(48, 32, dtype=torch.bool))
        >>> sampler.grid().shape, sampler.valid.shape
        (torch.Size([6, 48, 32, 2]), torch.Size([6, 48, 32]))
    """
    check_int(factor, "factor", 1)
    like = fit.coefficients
    h, w = reference_size or (math.ceil(fit.height / factor), math.ceil(fit.reference_width / factor))
    if coefficients is None:
        coefficients = sweep_coefficients(fit, block_centres(h, w, factor, like)).permute(2, 0, 1, 3)
    if tuple(coefficients.shape[1:3]) != (h, w):
        raise ShapeError(f"coefficients must be (N, {h}, {w}, 2), got {tuple(coefficients.shape)}")
    h_o, w_o = other_valid.shape
    width, height = w_o * factor, h_o * factor
    scale = coefficients.new_tensor([2.0 / width, 2.0 / height])
    offset = coefficients.new_tensor([(1.0 - 2.0 * other_start) / width - 1.0, 1.0 / height - 1.0])
    normalised = torch.cat([coefficients[:1] * scale + offset, coefficients[1:] * scale])
    if dtype is not None:
        normalised = normalised.to(dtype)
    if not precompute:
        return SweepSampler(normalised, num_hypotheses, other_valid=other_valid)
    probe = SweepSampler(normalised.detach(), num_hypotheses, other_valid=other_valid)
    valid = probe(torch.zeros(1, 1, h_o, w_o, dtype=normalised.dtype, device=normalised.device)).valid[0]
    return SweepSampler(normalised, num_hypotheses, valid=valid)
