"""The depth range to search: a default derived from the rig, and the check of a user's range.

Both rest on one exact quantity, the **co-visible fraction** c(Z) (:func:`covisible_fraction`): the share of
reference-half pixels whose scene point on the fronto-parallel plane at depth Z is also seen through the
right prism face (ray traced through the left face, then :func:`~prismstereo.geometry.projection.project_points`
into the right half). It is the pixel-level form of the thesis' common field of view (ch. 5, fig. 5.3-5.7):
near 0 at the prism's back plane, growing with Z as the two halves' fields of view overlap, 1 where they
coincide (setup 1: the Ray 1 / Ray 2 crossing near 1.40 m), then falling slowly (semi-divergent) or to 0
where a convergent common FOV closes.

Default range (:func:`default_z_range`):

* z_min is the nearest depth where the halves share a quarter of the reference view, c(z_min) = 0.25;
  nearer, most reference pixels have no match at all.
* z_max = 6 z_min: the hypotheses, uniform in 1/Z, then span 1/z_min - 1/z_max = (5/6)/z_min, five sixths of
  the inverse-depth (nearly: disparity) range between z_min and infinity, and the relative depth step of
  one pixel of disparity (~Z / (f B)) at z_max is six times that at z_min (setup 1: 0.22 % -> 1.33 %).
  The rule is scale-free, so a :meth:`~prismstereo.geometry.rig.BiPrismRig.downscaled` rig gets the same
  range. The thesis' working range, 228-1374 mm for both setups (Tables 4.3, 4.4), has the ratio 6.03.
* z_max is cut where c(Z) falls back below 0.25 (a convergent common FOV closing).

Setup 1 gives 222.1-1332.6 mm, setup 2 214.6-1287.7 mm (tests/depth/test_range.py).
"""

from __future__ import annotations

import math

import torch

from prismstereo.errors import PrismStereoError
from prismstereo.geometry.optics import points_at_depth, trace_pixels
from prismstereo.geometry.projection import project_points
from prismstereo.geometry.rig import BiPrismRig

__all__ = ["DepthRangeError", "covisible_fraction", "default_z_range", "check_z_range", "back_plane_depth"]

_F64 = torch.float64


class DepthRangeError(PrismStereoError, ValueError):
    """A depth range the rig cannot search: not beyond the prism, outside the common FOV, or not increasing."""


def back_plane_depth(rig: BiPrismRig) -> float:
    """Z of the prism's back plane, T_o + T (mm): no scene point can be nearer.

    Example:
        >>> round(back_plane_depth(thesis_setup1()), 1)
        175.6
    """
    return rig.apex_distance_mm + rig.prism_thickness_mm


def _reference_rays(rig: BiPrismRig, samples: tuple[int, int]):
    nu, nv = samples
    # cell centres of an nu x nv partition of the reference half (a midpoint-rule estimate of the fraction)
    u = (torch.arange(nu, dtype=_F64) + 0.5) * (rig.reference_width / nu) - 0.5
    v = (torch.arange(nv, dtype=_F64) + 0.5) * (rig.image_height / nv) - 0.5
    uv = torch.stack(torch.meshgrid(u, v, indexing="xy"), -1).reshape(-1, 2)
    rays = trace_pixels(rig, uv, "left")
    keep = rays.valid & rays.left
    if not bool(keep.any()):
        raise DepthRangeError("no reference-half pixel sees through the prism's left face")
    return type(rays)(*(field[keep] for field in rays))


def covisible_fraction(
    rig: BiPrismRig, depth: torch.Tensor | float, samples: tuple[int, int] = (33, 9)
) -> torch.Tensor:
    """c(Z): share of reference pixels whose point on the plane Z = depth is also seen by the right half.

    Exact ray optics at the cell centres of a ``samples`` = (columns, rows) partition of the reference half
    (a midpoint-rule estimate; positions whose ray misses the prism are left out). No occlusion: the plane
    is the only surface.

    Args:
        rig: the rig.
        depth: (D,) or scalar depths Z (mm), beyond the back plane.
        samples: grid size over the reference half.

    Returns:
        (D,) float64 fractions in [0, 1].

    Example:
        >>> c = covisible_fraction(thesis_setup1(), [228.0, 1400.0])
        >>> [round(x, 2) for x in c.tolist()]
        [0.27, 1.0]
    """
    z = torch.as_tensor(depth, dtype=_F64).reshape(-1)
    z_b = back_plane_depth(rig)
    if z.numel() == 0 or bool((~torch.isfinite(z) | (z <= z_b)).any()):
        raise DepthRangeError(f"depths must be finite and beyond the prism's back plane ({z_b:.1f} mm)")
    rays = _reference_rays(rig, samples)
    pts = points_at_depth(type(rays)(*(f.unsqueeze(0) for f in rays)), z[:, None])  # (D, N, 3)
    seen = project_points(rig, pts, "right").valid
    return seen.to(_F64).mean(-1)


def _bisect(rig: BiPrismRig, lo: float, hi: float, above_at_hi: bool, level: float, iterations: int = 18) -> float:
    """Depth in [lo, hi] where c(Z) crosses ``level`` (bisection in log Z, ~1e-6 relative from a scan step);
    c >= level at hi iff above_at_hi."""
    for _ in range(iterations):
        mid = math.sqrt(lo * hi)
        if (float(covisible_fraction(rig, mid)) >= level) == above_at_hi:
            hi = mid
        else:
            lo = mid
    return hi


def _scan(rig: BiPrismRig, far_factor: float = 50.0, steps: int = 32) -> tuple[torch.Tensor, torch.Tensor]:
    z_b = back_plane_depth(rig)
    z = torch.logspace(math.log10(z_b * (1 + 1e-4)), math.log10(z_b * far_factor), steps, dtype=_F64)
    # one depth per call: ~300 points stay below torch's intra-op threading grain (on a shared CPU the batched
    # call is many times slower through thread contention)
    return z, torch.cat([covisible_fraction(rig, zi) for zi in z])


def default_z_range(rig: BiPrismRig, min_covisible: float = 0.25, depth_ratio: float = 6.0) -> tuple[float, float]:
    """The default depth range (mm) searched for a rig (rule in the module docstring).

    z_min solves c(z_min) = ``min_covisible`` (the first crossing beyond the back plane: a log-spaced scan,
    then bisection to ~1e-6 relative); z_max = min(``depth_ratio`` z_min, the depth where c falls back below
    ``min_covisible``).

    Args:
        rig: the rig.
        min_covisible: co-visible share of the reference view required over the whole range, in (0, 1].
        depth_ratio: z_max / z_min, > 1.

    Returns:
        (z_min, z_max) in mm.

    Raises:
        DepthRangeError: bad arguments, or the halves never share ``min_covisible`` of the reference view.

    Example:
        >>> z0, z1 = default_z_range(thesis_setup1())
        >>> round(z0), round(z1)
        (222, 1333)
    """
    if not 0 < min_covisible <= 1:
        raise DepthRangeError(f"min_covisible must lie in (0, 1], got {min_covisible!r}")
    if not (math.isfinite(depth_ratio) and depth_ratio > 1):
        raise DepthRangeError(f"depth_ratio must be a finite number > 1, got {depth_ratio!r}")
    z, c = _scan(rig)
    above = c >= min_covisible
    if not bool(above.any()):
        raise DepthRangeError(f"the two halves never share {min_covisible:.0%} of the reference view (at most "
                              f"{float(c.max()):.1%}, at Z = {float(z[c.argmax()]):.0f} mm): no sensible depth range")
    i = int(above.to(torch.int8).argmax())
    z_min = float(z[0]) if i == 0 else _bisect(rig, float(z[i - 1]), float(z[i]), True, min_covisible)
    z_max = depth_ratio * z_min
    below = (~above) & (z > z[i]) & (z < z_max)
    if bool(below.any()):  # the common FOV narrows again (convergent) before depth_ratio * z_min
        j = int(below.to(torch.int8).argmax())
        z_max = _bisect(rig, float(z[j - 1]), float(z[j]), False, min_covisible)
    return z_min, z_max


def check_z_range(rig: BiPrismRig, z_range_mm: tuple[float, float]) -> tuple[float, float]:
    """Check a user's depth range (mm) against the rig and return it as floats.

    The range must increase, lie beyond the prism's back plane and, at both ends, inside the common field
    of view (c(Z) > 0, see :func:`covisible_fraction`); the message says where the common FOV starts or
    closes.

    Raises:
        DepthRangeError: with the reason and the rig's limits.

    Example:
        >>> check_z_range(thesis_setup1(), (250, 1000))
        (250.0, 1000.0)
    """
    try:
        z_min, z_max = (float(z) for z in z_range_mm)
    except (TypeError, ValueError) as exc:
        raise DepthRangeError(f"the depth range must be two numbers (z_min, z_max), got {z_range_mm!r}") from exc
    if not (math.isfinite(z_min) and math.isfinite(z_max)):
        raise DepthRangeError(f"the depth range must be finite, got {z_min:g} .. {z_max:g} mm")
    if z_max <= z_min:
        raise DepthRangeError(f"z_max ({z_max:g} mm) must be greater than z_min ({z_min:g} mm)")
    z_b = back_plane_depth(rig)
    if z_min <= z_b:
        raise DepthRangeError(f"z_min {z_min:g} mm is not beyond the prism's back plane at Z = {z_b:.1f} mm")
    c = covisible_fraction(rig, [z_min, z_max])
    if float(c[0]) > 0.0 and float(c[1]) > 0.0:
        return z_min, z_max
    z, cs = _scan(rig)
    seen = cs > 0
    if not bool(seen.any()):
        raise DepthRangeError("the two halves have no common field of view: nothing can be matched")
    i = int(seen.to(torch.int8).argmax())
    start = float(z[0]) if i == 0 else _bisect(rig, float(z[i - 1]), float(z[i]), True, 1e-12)
    if float(c[0]) == 0.0 and z_min < start:
        raise DepthRangeError(f"z_min {z_min:g} mm is before the common field of view of the two halves, "
                              f"which starts at Z = {start:.1f} mm")
    gone = (~seen) & (z > z[i])
    if bool(gone.any()):
        j = int(gone.to(torch.int8).argmax())
        span = f"Z = {start:.1f}-{_bisect(rig, float(z[j - 1]), float(z[j]), False, 1e-12):.1f} mm"
    else:
        span = f"Z > {start:.1f} mm, with gaps"
    bad = z_min if float(c[0]) == 0.0 else z_max
    raise DepthRangeError(f"the two halves have no common field of view at Z = {bad:g} mm (it spans {span})")
