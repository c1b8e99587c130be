"""``PrismStereo``: one bi-prism capture in, metric depth of the reference (left) half out.

The layers, in order: :class:`~prismstereo.matching.split.SplitImage` at the apex column; census bits of
both halves; the other half's bits sampled at the *exact* plane-sweep grid of every depth hypothesis
(:func:`~prismstereo.epipolar.grids.exact_sampling_grid`, precomputed and registered as a buffer);
Hamming costs; box and SGM aggregation; winner-take-all with equiangular sub-pixel refinement on the box
cost; depth by :func:`~prismstereo.depth.convert.index_to_depth`.

This first version samples with one ``grid_sample`` per hypothesis (exact, slow) and rejects occluded
pixels with a z-buffer test in the other half; the shift-band fast form and a symmetric left-right check
of the plane sweep come next.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.depth.convert import index_to_depth
from prismstereo.epipolar.grids import depth_hypotheses, exact_sampling_grid
from prismstereo.errors import OptionError, RigError, check_shape
from prismstereo.geometry.optics import points_at_depth, project_points, trace_pixels
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.matching.aggregate import box_filter, sgm_aggregate
from prismstereo.matching.cost import census_transform
from prismstereo.matching.select import subpixel_refine, uniqueness, winner_take_all
from prismstereo.matching.split import SplitImage

__all__ = ["DepthResult", "PrismStereo", "hypotheses_for_rig"]


class DepthResult(NamedTuple):
    """Depth of the reference half.

    Attributes:
        depth: (B, 1, H, W_ref) depth Z (mm); meaningless where not valid.
        valid: (B, 1, H, W_ref) bool.
        confidence: (B, 1, H, W_ref) in [0, 1].
        index: (B, 1, H, W_ref) fractional hypothesis index.
    """

    depth: torch.Tensor
    valid: torch.Tensor
    confidence: torch.Tensor
    index: torch.Tensor


def hypotheses_for_rig(rig: BiPrismRig, z_range_mm: tuple[float, float], max_step_px: float = 1.0) -> torch.Tensor:
    """Depth hypotheses uniform in 1/Z over ``z_range_mm`` with neighbours at most ``max_step_px`` apart in
    the right half (measured on the exact correspondences of a grid of reference pixels).

    Example:
        >>> hypotheses_for_rig(thesis_setup1(), (400.0, 700.0)).shape[0] > 10
        True
    """
    z0, z1 = z_range_mm
    if not rig.apex_distance_mm + rig.prism_thickness_mm < z0 < z1:
        raise RigError(f"z_range_mm must lie beyond the prism's back plane and increase, got {z_range_mm}")
    f64 = torch.float64
    u = torch.linspace(0.0, rig.reference_width - 1.0, 9, dtype=f64)
    v = torch.linspace(0.0, rig.image_height - 1.0, 7, dtype=f64)
    uv = torch.stack(torch.meshgrid(u, v, indexing="xy"), -1).reshape(-1, 2)
    rays = trace_pixels(rig, uv)
    near = project_points(rig, points_at_depth(rays, z0), "right")
    far = project_points(rig, points_at_depth(rays, z1), "right")
    ok = near.valid & far.valid
    span = (near.uv - far.uv).norm(dim=-1)[ok].max() if ok.any() else torch.tensor(rig.image_width / 2.0)
    num = max(2, math.ceil(float(span) / max_step_px * 1.02) + 1)
    return depth_hypotheses(z0, z1, num)


class PrismStereo(nn.Module):
    """Depth from one bi-prism capture by exact plane sweep.

    Args:
        rig: the rig.
        z_range_mm: (z_min, z_max) depth range searched.
        num_hypotheses: D; default so that neighbouring hypotheses are <= 1 px apart.
        census_window: census window (odd, >= 3).
        box: box aggregation window (odd).
        sgm: use 8-direction SGM after the box (P1, P2 in box-averaged Hamming units).
        p1, p2: SGM penalties.
        min_confidence: pixels with lower confidence are invalid.
        occlusion_tolerance: relative depth margin of the z-buffer occlusion test (:meth:`visible`), None to
            skip it.

    Example:
        >>> small = thesis_setup1().downscaled(8)
        >>> model = PrismStereo(small, (400.0, 700.0))
        >>> model(torch.rand(1, 1, 96, 128)).depth.shape
        torch.Size([1, 1, 96, 64])
    """

    def __init__(
        self,
        rig: BiPrismRig,
        z_range_mm: tuple[float, float],
        num_hypotheses: int | None = None,
        census_window: int = 5,
        box: int = 7,
        sgm: bool = True,
        p1: float = 16.0,
        p2: float = 128.0,
        min_confidence: float = 0.0,
        occlusion_tolerance: float | None = 0.01,
    ) -> None:
        super().__init__()
        if num_hypotheses is None:
            depths = hypotheses_for_rig(rig, z_range_mm)
        elif isinstance(num_hypotheses, int) and num_hypotheses >= 2:
            depths = depth_hypotheses(z_range_mm[0], z_range_mm[1], num_hypotheses)
        else:
            raise OptionError(f"num_hypotheses must be an int >= 2 or None, got {num_hypotheses!r}")
        grid = exact_sampling_grid(rig, depths)
        self.split = SplitImage(rig)
        self.register_buffer("depths", depths.to(torch.float32))
        self.register_buffer("grid", grid.normalised.to(torch.float32))  # (D, H, W_ref, 2)
        self.register_buffer("grid_valid", grid.valid)  # (D, H, W_ref)
        self.census_window, self.box, self.sgm = census_window, box, sgm
        self.p1, self.p2, self.min_confidence = p1, p2, min_confidence
        self.occlusion_tolerance = occlusion_tolerance

    def visible(self, index: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        """Occlusion test of the estimate (a z-buffer in the other half): each reference pixel's match is
        rounded to a right-half pixel; a pixel is visible when no other reference pixel with a point nearer
        than ``depth - occlusion_tolerance`` claims the same right-half pixel. Returns (B, 1, H, W_ref) bool.
        """
        b, _, h, w_ref = index.shape
        norm = self.grid.to(depth.dtype)  # (D, H, W_ref, 2) normalised coordinates of the other half
        hyp = index[:, 0]  # (B, H, W_ref)
        rows = torch.arange(h, device=index.device).view(1, h, 1).expand_as(hyp)
        cols = torch.arange(w_ref, device=index.device).view(1, 1, w_ref).expand_as(hyp)
        g = norm[hyp, rows, cols]  # (B, H, W_ref, 2)
        w_o = self.split.width - self.split.split
        x = torch.round(((g[..., 0] + 1) * w_o - 1) / 2).long().clamp(0, w_o - 1)
        y = torch.round(((g[..., 1] + 1) * h - 1) / 2).long().clamp(0, h - 1)
        target = (y * w_o + x).view(b, -1)
        z = depth.view(b, -1)
        zbuf = torch.full((b, h * w_o), float("inf"), dtype=z.dtype, device=z.device)
        zbuf = zbuf.scatter_reduce(1, target, z, reduce="amin")
        nearest = zbuf.gather(1, target)
        return (z <= nearest + self.occlusion_tolerance * z).view(b, 1, h, w_ref)

    @property
    def num_hypotheses(self) -> int:
        """D, the number of depth hypotheses."""
        return int(self.depths.shape[0])

    def cost_volume(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, D, H, W_ref) box-aggregated Hamming costs and the (D, H, W_ref) sampling validity."""
        ref, other = self.split(image)
        bits_ref = census_transform(ref, self.census_window)
        bits_other = census_transform(other, self.census_window)
        b, k, h, w_o = bits_other.shape
        d, _, w_ref, _ = self.grid.shape
        grid = self.grid.to(image.dtype)
        costs = []
        for i in range(d):  # one grid_sample per hypothesis: exact but slow (see module docstring)
            sampled = F.grid_sample(bits_other, grid[i].expand(b, -1, -1, -1), mode="bilinear",
                                    padding_mode="border", align_corners=False)
            costs.append((bits_ref - sampled).abs().sum(1))
        volume = torch.stack(costs, dim=1)
        worst = torch.full_like(volume, float(k))
        volume = torch.where(self.grid_valid.unsqueeze(0), volume, worst)
        return box_filter(volume, self.box), self.grid_valid

    def forward(self, image: torch.Tensor) -> DepthResult:
        """Depth of the reference half of ``image`` (B, C, H, W) in [0, 1]."""
        check_shape(image, ["B", "C", "H", "W"], "image")
        local, grid_valid = self.cost_volume(image)
        cost = sgm_aggregate(local, self.p1, self.p2, 8) if self.sgm else local
        index, _ = winner_take_all(cost)
        refined = subpixel_refine(local, index, "equiangular")
        _, confidence = uniqueness(cost, index, 1.0)
        sampled_ok = grid_valid.unsqueeze(0).expand(cost.shape).gather(1, index)
        valid = sampled_ok & (confidence >= self.min_confidence)
        depth = index_to_depth(refined, self.depths.to(refined.dtype))
        if self.occlusion_tolerance is not None:
            valid = valid & self.visible(index, depth)
        return DepthResult(depth, valid, torch.where(valid, confidence, torch.zeros_like(confidence)), refined)
