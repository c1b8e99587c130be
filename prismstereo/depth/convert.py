"""Conversions between matching coordinates and metric depth, by the exact geometry.

* Hypothesis index <-> depth: the matcher's (sub-pixel) index along the depth hypotheses z_0..z_{D-1}
  maps to depth by linear interpolation of 1/Z between neighbouring hypotheses (exact at integer indices,
  and everywhere for hypotheses uniform in inverse depth).
* Disparity <-> depth: disparity is the horizontal distance (full-sensor px) from a reference pixel to the
  right-half pixel that sees the same point, d = u_right - u_ref. It is computed from the exact optics
  (ray tracing and :func:`~prismstereo.geometry.projection.project_points`), not the small-angle depth
  equation 6.15; depth from disparity solves that relation for Z by Newton steps on 1/Z.
"""

from __future__ import annotations

import torch

from prismstereo.errors import RigError, check_shape
from prismstereo.geometry.optics import points_at_depth, trace_pixels
from prismstereo.geometry.parameters import RigParameters
from prismstereo.geometry.projection import project_points
from prismstereo.geometry.rig import BiPrismRig

__all__ = ["index_to_depth", "depth_to_index", "depth_to_disparity", "disparity_to_depth"]


def _check_depths(depths: torch.Tensor) -> None:
    check_shape(depths, ["D"], "depths")
    if depths.shape[0] < 2:
        raise RigError("need at least 2 depth hypotheses")


def index_to_depth(index: torch.Tensor, depths: torch.Tensor) -> torch.Tensor:
    """Depth (mm) of a continuous hypothesis index (any shape), linear in 1/Z between hypotheses.

    Indices outside [0, D-1] extrapolate linearly in 1/Z. Differentiable w.r.t. ``index``.

    Example:
        >>> index_to_depth(torch.tensor([0.0, 0.5, 1.0]), torch.tensor([250.0, 500.0]))
        tensor([250.0000, 333.3333, 500.0000])
    """
    _check_depths(depths)
    inv = 1.0 / depths.to(index)
    i0 = torch.floor(index.detach()).clamp(0, depths.shape[0] - 2).long()
    a = index - i0
    return 1.0 / ((1 - a) * inv[i0] + a * inv[i0 + 1])


def depth_to_index(depth: torch.Tensor, depths: torch.Tensor) -> torch.Tensor:
    """Continuous hypothesis index of depths (any shape); the inverse of :func:`index_to_depth`.

    ``depths`` must be monotonic in 1/Z (as :func:`~prismstereo.epipolar.grids.depth_hypotheses` gives).

    Example:
        >>> depth_to_index(torch.tensor([333.3333]), torch.tensor([250.0, 500.0]))
        tensor([0.5000])
    """
    _check_depths(depths)
    inv = 1.0 / depths.to(depth)
    descending = bool(inv[0] > inv[-1])
    key = -inv if descending else inv
    target = -1.0 / depth if descending else 1.0 / depth
    i0 = (torch.searchsorted(key.contiguous(), target.detach().reshape(-1).contiguous()) - 1)
    i0 = i0.clamp(0, depths.shape[0] - 2).reshape(depth.shape)
    return i0 + (1.0 / depth - inv[i0]) / (inv[i0 + 1] - inv[i0])


def depth_to_disparity(rig: BiPrismRig | RigParameters, uv_ref: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
    """Exact disparity u_right - u_ref (px) of reference pixels (*, 2) whose points are at depth (*) mm.

    NaN where the point is not seen through the right face (see :func:`project_points`'s ``valid``).

    Example:
        >>> uv = torch.tensor([[400.0, 300.0]], dtype=torch.float64)
        >>> depth_to_disparity(thesis_setup1(), uv, torch.tensor([525.0], dtype=torch.float64)).shape
        torch.Size([1])
    """
    check_shape(uv_ref, ["*", 2], "uv_ref")
    rays = trace_pixels(rig, uv_ref)
    proj = project_points(rig, points_at_depth(rays, depth), "right")
    disparity = proj.uv[..., 0] - uv_ref[..., 0]
    return torch.where(proj.valid & rays.valid & rays.left, disparity, torch.full_like(disparity, float("nan")))


def disparity_to_depth(
    rig: BiPrismRig | RigParameters,
    uv_ref: torch.Tensor,
    disparity: torch.Tensor,
    z_range_mm: tuple[float, float] = (200.0, 5000.0),
    iterations: int = 6,
) -> torch.Tensor:
    """Exact depth (mm) from disparity d = u_right - u_ref for reference pixels (*, 2).

    Newton's method on w = 1/Z (the disparity is nearly linear in 1/Z), started from the chord between
    ``z_range_mm``; a fixed number of steps (ONNX friendly), the last one carrying the implicit-function
    gradient, so the result is differentiable w.r.t. disparity and rig parameters. NaN where the solution
    leaves the right half's view.

    Example:
        >>> rig = thesis_setup1(); uv = torch.tensor([[400.0, 300.0]], dtype=torch.float64)
        >>> d = depth_to_disparity(rig, uv, torch.tensor([525.0], dtype=torch.float64))
        >>> disparity_to_depth(rig, uv, d)
        tensor([525.0000], dtype=torch.float64)
    """
    check_shape(uv_ref, ["*", 2], "uv_ref")
    z0, z1 = z_range_mm
    if not 0 < z0 < z1:
        raise RigError(f"z_range_mm must satisfy 0 < z_min < z_max, got {z_range_mm}")
    rays = trace_pixels(rig, uv_ref)
    u_ref = uv_ref[..., 0]

    def disparity_at(w: torch.Tensor, start: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        proj = project_points(rig, points_at_depth(rays, 1.0 / w), "right", iterations=3 if start is not None else 5,
                              initial_uv=start)
        return proj.uv[..., 0] - u_ref, proj

    with torch.no_grad():
        w_a = torch.full_like(u_ref, 1.0 / z0)
        w_b = torch.full_like(u_ref, 1.0 / z1)
        d_a, _ = disparity_at(w_a, None)
        d_b, _ = disparity_at(w_b, None)
        w = w_a + (disparity.detach() - d_a) * (w_b - w_a) / (d_b - d_a)
        start = None
        for _ in range(iterations):
            d_w, proj = disparity_at(w, start)
            start = proj.uv
            h = 1e-7 * w.abs().clamp_min(1e-6)
            d_h, _ = disparity_at(w + h, start)
            slope = (d_h - d_w) / h
            w = (w - (d_w - disparity.detach()) / slope).clamp(1.0 / (50.0 * z1), 1.0 / (0.5 * z0))
    # final step with gradients: w* - (d(w*) - disparity) / slope
    d_w, proj = disparity_at(w.detach(), start)
    w = w.detach() - (d_w - disparity) / slope
    depth = 1.0 / w
    ok = proj.valid & rays.valid & rays.left
    return torch.where(ok, depth, torch.full_like(depth, float("nan")))
