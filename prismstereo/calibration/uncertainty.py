"""How uncertain depth is because of the calibration: the rig's covariance propagated to triangulated depth.

A calibration estimates the rig to within a covariance (:attr:`~prismstereo.calibration.fit.CalibrationResult.
covariance`: the fit's for the estimated parameters, the tolerance for the ones held fixed or unobservable).
A depth the model later measures is the triangulation of a pixel pair through that rig, so its error due to the
calibration alone is, to first order, sigma_Z^2 = j C j^T with j = dZ/d(rig) at fixed pixels (forward-mode
autograd through the exact tracer and the thesis' mid-point theorem, Appendix C). :func:`depth_uncertainty`
evaluates it on a grid of reference pixels at given depths: the number to compare with the matching's own error
(a calibrated depth cannot be better than either).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import torch
from torch.func import jacfwd

from prismstereo.calibration.parameters import rig_parameters, rig_vector
from prismstereo.errors import CalibrationError
from prismstereo.geometry.optics import points_at_depth, trace_pixels
from prismstereo.geometry.projection import project_points
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.geometry.virtual_camera import ray_midpoint

__all__ = ["DepthUncertainty", "depth_uncertainty"]

F64 = torch.float64


class DepthUncertainty(NamedTuple):
    """Result of :func:`depth_uncertainty`.

    Attributes:
        depth_mm: (K,) the depths evaluated.
        relative_std: (K,) RMS over the grid's co-visible pixels of sigma_Z / Z.
        pixels: (K,) number of co-visible grid pixels behind each value.
        share: (16,) for each rig parameter, the fraction of the depth variance (over all those pixels and depths)
            that knowing it exactly would remove: (j C e_i)^2 / C_ii, with its correlations (the shares of
            correlated parameters overlap and need not sum to 1): what to determine better to lower the uncertainty.
    """

    depth_mm: torch.Tensor
    relative_std: torch.Tensor
    pixels: torch.Tensor
    share: torch.Tensor | None = None


def depth_uncertainty(rig: BiPrismRig, covariance: torch.Tensor, depths_mm: Sequence[float],
                      grid: int = 9) -> DepthUncertainty:
    """Relative depth uncertainty caused by a rig's covariance, at fronto-parallel depths.

    Args:
        rig: the (calibrated) rig.
        covariance: (16, 16) covariance of :func:`~prismstereo.calibration.parameters.rig_vector` (internal units).
        depths_mm: depths Z to evaluate.
        grid: ``grid`` x ``grid`` reference pixels over the left half.

    Returns:
        DepthUncertainty.

    Raises:
        CalibrationError: covariance of the wrong shape or no depth.

    Example:
        >>> cov = torch.zeros(16, 16, dtype=torch.float64); cov[11, 11] = (0.1 * 3.14159 / 180) ** 2  # alpha 0.1 deg
        >>> u = depth_uncertainty(thesis_setup1(), cov, [600.0])
        >>> 0.03 < float(u.relative_std[0]) < 0.05  # alpha sets the convergence of the halves: ~4 %
        True
    """
    if covariance.shape != (16, 16):
        raise CalibrationError(f"covariance must be (16, 16), got {tuple(covariance.shape)}")
    if len(depths_mm) == 0:
        raise CalibrationError("no depth to evaluate")
    u = torch.linspace(0.05, 0.95, grid, dtype=F64) * (rig.reference_width - 1)
    v = torch.linspace(0.05, 0.95, grid, dtype=F64) * (rig.image_height - 1)
    left = torch.stack(torch.meshgrid(u, v, indexing="xy"), -1).reshape(-1, 2)
    base = rig_vector(rig)
    rays = trace_pixels(rig, left, "left")
    out, count = [], []
    parts, total = torch.zeros(16, dtype=F64), 0.0
    cov = covariance.to(F64)
    diagonal = cov.diagonal().clamp_min(1e-300)
    for z in depths_mm:
        proj = project_points(rig, points_at_depth(rays, float(z)), "right")
        ok = proj.valid & rays.valid
        lp, rp = left[ok], proj.uv[ok]

        def depth_of(vector: torch.Tensor, lp: torch.Tensor = lp, rp: torch.Tensor = rp) -> torch.Tensor:
            p = rig_parameters(vector, rig, distorted=True)
            a, b = trace_pixels(p, lp, "left"), trace_pixels(p, rp, "right")
            return ray_midpoint(a.origins, a.directions, b.origins, b.directions)[:, 2]

        if lp.shape[0] == 0:
            out.append(float("nan"))
            count.append(0)
            continue
        j = jacfwd(depth_of)(base)  # (N, 16)
        jc = j @ cov  # (N, 16)
        var = (jc * j).sum(dim=1).clamp_min(0)
        parts += (jc.pow(2) / diagonal).mean(dim=0) / float(z) ** 2  # each parameter known exactly: var - this
        total += float(var.mean()) / float(z) ** 2
        out.append(float((var / float(z) ** 2).mean().sqrt()))
        count.append(int(lp.shape[0]))
    share = (parts / total).clamp(0.0, 1.0) if total > 0 else parts
    return DepthUncertainty(torch.tensor([float(z) for z in depths_mm], dtype=F64), torch.tensor(out, dtype=F64),
                            torch.tensor(count), share)
