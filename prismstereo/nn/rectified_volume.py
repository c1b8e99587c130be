"""A learned-feature cost volume by column shifts on row-rectified feature maps: the fast form of
:class:`~prismstereo.nn.PrismCostVolume` for exported graphs.

Both halves of a feature map at 1/``scale`` are warped vertically so that every reference pixel and its exact
correspondences at every depth share one row (:func:`~prismstereo.epipolar.row_rectify.fit_row_rectification`, fitted
to the exact sweep of thesis eq. 3.1-3.10; residual 1.6e-4 px on ``thesis_setup1``, 0.1 px on ``thesis_setup2`` at full
resolution, a scale-th of that here). Hypothesis k then compares rectified reference column u with rectified other
column u + k: the volume is one gather of whole rows (columns as rows, the layout onnxruntime copies fastest) and a
product, where :class:`~prismstereo.nn.PrismCostVolume` samples every (hypothesis, pixel) bilinearly (onnxruntime's
GridSample runs on one thread). The shifts are whole pixels at 1/scale, nearly uniform in the sweep coordinate s
(disparity is nearly linear in 1/Z); a fractional shift becomes s exactly through each pixel's tabulated sweep
(:func:`~prismstereo.epipolar.sweep_table.column_to_sweep`), and maps go back to the reference grid by the
rectification's inverse (:attr:`~prismstereo.epipolar.row_rectify.RectifiedLevel.back_grid`).

The volume works in the transposed layout (B, G, D, W_l, H_r): columns as rows. Networks on it see images transposed.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.epipolar.row_rectify import fit_row_rectification, rectified_level
from prismstereo.epipolar.sweep import fit_sweep
from prismstereo.epipolar.sweep_table import column_to_sweep, cubic_at, local_cubic
from prismstereo.errors import OptionError, ShapeError, check_int, check_shape
from prismstereo.geometry.optics import check_rig_images, trace_pixels
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.matching.aggregate import box_filter
from prismstereo.runtime import sample_bilinear, sample_grid

__all__ = ["RectifiedCostVolume"]


class RectifiedCostVolume(nn.Module):
    """Group-wise correlation of the two halves of a feature map by column shifts on row-rectified rows.

    Args:
        rig: the full-resolution rig; its sensor's sides must be multiples of ``scale`` (the split need not be).
        z_range_mm: (z_min, z_max) mm: the shifts span every reference pixel's correspondences over it.
        scale: the features' downsampling relative to the sensor (feature pixel j centred on sensor pixel
            scale j + (scale - 1) / 2).
        groups: G >= 1 correlation groups.

    Attributes:
        shifts: (D,) buffer, the integer shifts (px at 1/scale), ascending.
        valid: (D, W_l, H_r) bool buffer, transposed layout: the rectified reference pixel and its shifted sample are
            real and the shift lies within the pixel's searched range.
        columns: (W_l,) buffer, the full-sensor column of each rectified reference column; shift k reaches
            columns + k scale in the other half.
        height, width, reference_width: the feature map's (h, W_b) and the reference level's columns w_l (the
            feature columns that hold the reference half, the last one possibly shared with the other half).

    Raises:
        OptionError: a sensor that ``scale`` does not divide, bad ``scale`` or ``groups``. RigError: bad rig or range.

    Example:
        >>> volume = RectifiedCostVolume(thesis_setup1().downscaled(4), (450.0, 1000.0), scale=8, groups=2)
        >>> cost = volume(torch.rand(1, 8, 24, 32))
        >>> cost.shape[:3] == (1, 2, volume.num_hypotheses), tuple(cost.shape[3:]) == tuple(volume.valid.shape[1:])
        (True, True)
    """

    shifts: torch.Tensor
    valid: torch.Tensor

    def __init__(self, rig: BiPrismRig, z_range_mm: tuple[float, float], scale: int = 8, *, groups: int = 1) -> None:
        super().__init__()
        check_rig_images(rig)
        self.scale = f = check_int(scale, "scale", 1)
        self.groups = check_int(groups, "groups", 1)
        w_ref, h, w = rig.reference_width, rig.image_height, rig.image_width
        if h % f or w % f:
            raise OptionError(f"the rectified volume needs a sensor whose sides are multiples of {f}, got {w}x{h}")
        fit = fit_sweep(rig, z_range_mm)
        f64 = torch.float64
        u_o, v = torch.arange(w_ref, w, dtype=f64), torch.arange(h, dtype=f64)
        rays = trace_pixels(rig, torch.stack(torch.meshgrid(u_o, v, indexing="xy"), -1))
        level = rectified_level(fit_row_rectification(rig, fit), fit, f, rays.valid & ~rays.left)
        self.height, self.width = h // f, w // f
        self.reference_width = level.reference_grid.shape[1]  # ceil(w_ref / f): the reference level's columns
        # the other level's pixel x (other-half columns f x ... f x + f - 1) is feature column x + w_ref / f: its grid
        # normalised on the whole feature map, so that a split between feature columns needs no second resampling
        other = level.other_grid.clone()
        x = (other[..., 0] + 1.0) * other.shape[1] / 2 - 0.5 + w_ref / f
        other[..., 0] = (2.0 * x + 1.0) / self.width - 1.0
        dtype = torch.get_default_dtype()
        self.register_buffer("other_grid", other.to(dtype), persistent=False)
        for name in ("reference_grid", "back_grid", "table", "shifts"):
            self.register_buffer(name, getattr(level, name).to(dtype), persistent=False)
        self.register_buffer("index", level.index.reshape(-1), persistent=False)  # (D W_l,) rows of the transposed
        self.register_buffer("valid", level.valid.transpose(-1, -2).contiguous(), persistent=False)
        # the rectified reference pixels with a valid shift (1, 1, H_r, W_l), and the full-sensor column of each
        # rectified reference column u: a shift k (px at 1/scale) reaches column columns[u] + k scale
        self.register_buffer("rectified_covered", level.valid.any(0).to(dtype).view(1, 1, *level.valid.shape[1:]),
                             persistent=False)
        u = (torch.arange(self.reference_width, dtype=f64) + 0.5) * f - 0.5
        self.register_buffer("columns", (u + w_ref).to(dtype), persistent=False)

    @property
    def num_hypotheses(self) -> int:
        """D, the shifts."""
        return int(self.shifts.numel())

    def rectified_reference(self, features: torch.Tensor) -> torch.Tensor:
        """(B, C, W_l, H_r) the reference half of ``features`` (B, C, h, W_b) rectified, transposed."""
        return _warp(features[..., :self.reference_width], self.reference_grid.to(features)).transpose(-1, -2)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """The cost volume of ``features`` (B, C, h, W_b) of the whole capture at 1/scale.

        Returns:
            (B, G, D, W_l, H_r): the channel mean of the product within each group, 0 where not :attr:`valid`.

        Raises:
            ShapeError: features not (B, C, h, W_b) of the binned sensor, or C not a multiple of ``groups``.
        """
        check_shape(features, ["B", "C", "H", "W"], "features")
        b, c = features.shape[:2]
        if tuple(features.shape[-2:]) != (self.height, self.width) or c % self.groups:
            raise ShapeError(f"features must be (B, C, {self.height}, {self.width}) with C a multiple of "
                             f"{self.groups}, got {tuple(features.shape)}")
        reference = self.rectified_reference(features)  # (B, C, W_l, H_r)
        other = _warp(features, self.other_grid.to(features)).transpose(-1, -2)  # (B, C, W_ol, H_r)
        d, (w_l, h_r) = self.num_hypotheses, reference.shape[-2:]
        shifted = other.index_select(2, self.index).view(b, c, d, w_l, h_r)  # whole rows: a copy each
        product = (shifted * reference.unsqueeze(2)).view(b, self.groups, c // self.groups, d, w_l, h_r)
        return product.mean(2) * self.valid.to(features.dtype)

    def to_sweep(self, shift: torch.Tensor) -> torch.Tensor:
        """Fractional shifts (B, 1, W_l, H_r) (transposed, as the volume) -> sweep coordinates (B, 1, H_r, W_l) of the
        rectified reference pixels (exact through each pixel's tabulated sweep)."""
        column = self.columns.to(shift) + shift.transpose(-1, -2) * self.scale  # full-sensor column of the match
        return column_to_sweep(self.table.to(shift), column)

    def back(self, maps: torch.Tensor, mode: str = "bilinear") -> torch.Tensor:
        """Maps (B, C, H_r, W_l) of the rectified reference grid on the reference grid (B, C, h, w_l): bilinear, or the
        nearest rectified pixel's value (``mode='nearest'``); beyond the edge rows, the edge's.

        The rectified grid's edge rows lie partly outside the image (no valid hypothesis there): bilinear maps are
        first extended over the rectified pixels without one from their 3 x 3 neighbours that have one, so that the
        reference rows between them and the image take only real values.
        """
        if mode == "nearest":
            grid = self.back_grid.to(maps).unsqueeze(0).expand(maps.shape[0], -1, -1, -1)
            return F.grid_sample(maps, grid, mode="nearest", padding_mode="border", align_corners=False)
        covered = self.rectified_covered.to(maps)
        weight = box_filter(covered, 3)
        filled = box_filter(maps * covered, 3) / weight.clamp_min(1e-6)
        maps = maps * covered + filled * (1.0 - covered)
        return _warp(maps, self.back_grid.to(maps))

    def covered(self) -> torch.Tensor:
        """(1, 1, h, w_l) 1 where a reference level pixel's rectified neighbours have a valid hypothesis, else 0."""
        grid = self.back_grid.unsqueeze(0)
        return (F.grid_sample(self.rectified_covered.to(grid), grid, mode="bilinear", padding_mode="border",
                              align_corners=False) > 0).to(grid.dtype)

    def truth_shift(self, s: torch.Tensor, known: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The true fractional shift index (into :attr:`shifts`) of every rectified reference pixel, transposed
        (B, 1, W_l, H_r), and where it is known, from true sweep coordinates ``s`` and ``known`` (B, 1, h, w_l) on the
        reference grid (training's target).
        """
        grid = self.reference_grid.to(s).unsqueeze(0).expand(s.shape[0], -1, -1, -1)
        filled = torch.where(known, s, torch.zeros_like(s))
        s_r = sample_grid(filled, grid).clamp(-1.0, 1.0)
        # every bilinear tap known
        known_r = F.grid_sample(known.to(s.dtype), grid, mode="bilinear", padding_mode="zeros",
                                align_corners=False) > 0.999
        cubic = local_cubic(self.table.to(s), s_r)
        column = cubic_at(cubic, cubic.u)[..., 0]  # (B, 1, H_r, W_l) full-sensor column
        shift = (column - self.columns.to(s)) / self.scale - self.shifts[0].to(s)
        return shift.transpose(-1, -2), known_r.transpose(-1, -2)


def _warp(features: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """``features`` (B, C, h, w) sampled bilinearly at the fixed ``grid`` (H', W', 2) (``grid_sample``'s normalised
    positions, border padding): (B, C, H', W'). Exported, the taps are gathered
    (:func:`~prismstereo.runtime.sample_bilinear`): onnxruntime's GridSample runs on one thread."""
    h, w = features.shape[-2:]
    x = ((grid[..., 0] + 1.0) * w - 1.0) / 2.0
    y = ((grid[..., 1] + 1.0) * h - 1.0) / 2.0
    b = features.shape[0]
    return sample_bilinear(features, x.expand(b, 1, -1, -1), y.expand(b, 1, -1, -1))[:, :, 0]
