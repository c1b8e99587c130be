"""The exact field of view by ray tracing, and its comparison with the chapter 5 closed forms.

Companion of :mod:`prismstereo.analysis.fov` and :mod:`prismstereo.analysis.fov_formulas`:
:func:`exact_fov_extent` traces a sensor row through the real prism (truncation by the prism's edge and total
internal reflection included), :func:`compare_fov` and :func:`fov_alpha_sweep` report the difference to the closed
forms.
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

import torch

from prismstereo.analysis._common import AnalysisError, as_tensor, check_rig, depths_beyond
from prismstereo.analysis.fov import FOVExtent, fov_closed_form, fov_extent
from prismstereo.analysis.fov_formulas import FOVType, fov_type_from_epsilon
from prismstereo.errors import check_option
from prismstereo.geometry.optics import apex_ray, points_at_depth, trace_pixels
from prismstereo.geometry.rig import BiPrismRig

__all__ = ["FOVComparison", "FOVSweep", "exact_fov_extent", "exact_fov_type", "compare_fov", "fov_alpha_sweep"]


class FOVComparison(NamedTuple):
    """Closed form vs exact FOV. ``difference`` (D,) is the largest |closed - exact| of the four half bounds
    and the common width (mm); ``worst`` its maximum."""

    closed_form: FOVExtent
    exact: FOVExtent
    difference: torch.Tensor
    worst: float


class FOVSweep(NamedTuple):
    """Closed form vs exact over prism angles: (A,) angles (deg), worst difference (mm), Table 5.1 types."""

    alpha_deg: torch.Tensor
    worst: torch.Tensor
    fov_types: list[str]


# ----------------------------------------------------------------------------------- angles (eq. 5.1-5.12)
def exact_fov_extent(
    rig: BiPrismRig, depth: torch.Tensor | float, row: float | None = None, samples: int = 2049
) -> FOVExtent:
    """The exact extents by ray tracing one sensor row through the prism.

    Traces ``samples`` pixels evenly over the row from the sensor edge u = -0.5 to u = W - 0.5, plus the
    two rays at the apex column (nudged 1e-10 px into each half: the halves' inner borders); each half's extent
    at depth Z is the min/max x of its valid rays (rays that miss the prism or are totally internally
    reflected are excluded, so truncation by the prism's edge shows, to within one sample spacing).

    Args:
        rig: any rig (tilt allowed).
        depth: (D,) or scalar depths (mm), beyond the back plane.
        row: sensor row v (default the principal point's row, the thesis' top view).
        samples: pixels per row (>= 3).

    Returns:
        FOVExtent, float64.

    Example:
        >>> ext = exact_fov_extent(thesis_setup1(), [1000.0])
        >>> round(float(ext.width[0]), 2)
        89.13
    """
    check_rig(rig)
    if not isinstance(samples, int) or samples < 3:
        raise AnalysisError(f"samples must be an int >= 3, got {samples!r}")
    f64 = torch.float64
    v = rig.cy if row is None else float(row)
    if not -0.5 <= v <= rig.image_height - 0.5:
        raise AnalysisError(f"row {v} is off the sensor (0 .. {rig.image_height - 1})")
    u = torch.linspace(-0.5, rig.image_width - 0.5, samples, dtype=f64)
    uv = torch.stack([u, torch.full_like(u, v)], -1)
    rays = trace_pixels(rig, uv)
    # The inner borders: the apex column nudged 1e-10 px into each half (exactly at the apex the face test
    # is a rounding-level tie).
    inner = [trace_pixels(rig, torch.tensor([[rig.apex_column + s * 1e-10, v]], dtype=f64), half)
             for s, half in ((-1.0, "left"), (1.0, "right"))]
    z_max = max(float(rays.origins[..., 2].max()), rig.apex_distance_mm + rig.prism_thickness_mm)
    depth = depths_beyond(depth, z_max)
    bounds = []
    for k, is_left in enumerate((True, False)):
        x = points_at_depth(rays, depth[:, None])[..., 0]
        mask = rays.valid & (rays.left == is_left)
        xi = points_at_depth(inner[k], depth[:, None])[..., 0]
        x = torch.cat([x, xi], -1)
        mask = torch.cat([mask, inner[k].valid])
        if not bool(mask.any()):
            raise AnalysisError(f"no valid ray in the {'left' if is_left else 'right'} half of row {v}")
        inf = torch.full_like(x, math.inf)
        bounds.append(torch.stack([torch.where(mask, x, inf).amin(-1), torch.where(mask, x, -inf).amax(-1)], -1))
    return FOVExtent.from_halves(depth, bounds[0], bounds[1])


def exact_fov_type(rig: BiPrismRig) -> FOVType:
    """Table 5.1 type from traced rays: phi_2 = half the angle between the two apex rays, phi_4 = the mean
    outward angle of the two sensor-edge rays (centre row), epsilon = phi_4 / phi_2.

    Example:
        >>> exact_fov_type(thesis_setup1())
        'semi-divergent'
    """
    check_rig(rig)
    f64 = torch.float64
    apex = [apex_ray(rig, half) for half in ("left", "right")]
    phi2 = 0.5 * (math.atan2(float(apex[0].directions[0]), float(apex[0].directions[2]))
                  - math.atan2(float(apex[1].directions[0]), float(apex[1].directions[2])))
    edges = trace_pixels(rig, torch.tensor([[-0.5, rig.cy], [rig.image_width - 0.5, rig.cy]], dtype=f64))
    ang = torch.atan2(edges.directions[:, 0], edges.directions[:, 2])
    phi4 = 0.5 * float(ang[1] - ang[0])
    return fov_type_from_epsilon(phi4 / phi2)  # type: ignore[return-value]


def compare_fov(rig: BiPrismRig, depth: torch.Tensor | float, samples: int = 2049) -> FOVComparison:
    """Closed-form extents (:func:`fov_extent`) against the exact ones (:func:`exact_fov_extent`, centre row).

    Example:
        >>> compare_fov(thesis_setup1(), [500.0, 2000.0]).worst < 1e-9
        True
    """
    closed = fov_extent(fov_closed_form(rig), depth)
    exact = exact_fov_extent(rig, closed.depth, samples=samples)
    diff = torch.cat([(closed.left - exact.left).abs(), (closed.right - exact.right).abs(),
                      (closed.width - exact.width).abs()[:, None]], -1).amax(-1)
    return FOVComparison(closed, exact, diff, float(diff.max()))


def fov_alpha_sweep(
    rig: BiPrismRig,
    alphas_deg: torch.Tensor | list[float],
    depth: torch.Tensor | float,
    keep: Literal["width", "thickness"] = "width",
    samples: int = 2049,
) -> FOVSweep:
    """Compare closed form and exact FOV over prism angles.

    Args:
        rig: the base rig (alpha replaced).
        alphas_deg: (A,) prism angles in degrees.
        depth: depths (mm) at which the extents are compared.
        keep: 'width' keeps the back plane 2 T / tan(alpha) (T follows alpha, the thesis' b = 100 mm part);
            'thickness' keeps T (the prism narrows as alpha grows, until edge rays miss it).
        samples: pixels per row of the exact trace.

    Returns:
        FOVSweep(alpha_deg (A,), worst (A,) mm, fov_types).

    Example:
        >>> sweep = fov_alpha_sweep(thesis_setup1(), [3.0, 6.4, 15.0], [400.0, 1500.0])
        >>> sweep.fov_types, bool(sweep.worst.max() < 1e-9)
        (['divergent', 'semi-divergent', 'convergent'], True)
    """
    check_rig(rig)
    check_option(keep, ("width", "thickness"), "keep")
    alphas = as_tensor(alphas_deg, name="alphas_deg").reshape(-1).to(torch.float64)
    half_width = rig.prism_width_mm / 2
    worst, types = [], []
    for a in alphas.tolist():
        changes: dict[str, float] = {"alpha_deg": a}
        if keep == "width":
            changes["prism_thickness_mm"] = half_width * math.tan(math.radians(a))
        r = rig.replace(**changes)
        worst.append(compare_fov(r, depth, samples).worst)
        types.append(fov_closed_form(r).fov_type)
    return FOVSweep(alphas, torch.tensor(worst, dtype=torch.float64), types)
