"""A rig's field of view by the closed forms of thesis chapter 5: its four border rays and the extents they bound.

Every quantity is in the top view (the x-z plane of the camera frame, the sensor's centre row) like the
thesis' figures 5.3-5.7. Conventions (:mod:`prismstereo.conventions`): x right, z forward, mm, radians;
the left half-image (rays through the face at x < d) is the reference view.

Each half sees a wedge bounded by two rays leaving the back plane z_b = T_o + T (their angles and intercepts as
functions of the prism's and the camera's numbers: :mod:`prismstereo.analysis.fov_formulas`):

* **Ray 1** (eq. 5.5, 5.16): the camera ray through the apex, refracted by the half's face. It is the
  half's virtual optical axis and its *inner* border: the left half's Ray 1 leaves at x = +h with angle
  +phi_2 (toward +x), the right half's at x = -h with angle -phi_2.
* **Ray 2** (eq. 5.9, 5.25): the ray of the sensor's outer edge pixel, the half's *outer* border: the left
  half's leaves at x = -v with angle -phi_4, the right half's at x = +v with angle +phi_4.

A line is stored as :class:`RayLine`, x(Z) = intercept + (Z - z_b) tan(angle), angles signed (positive turns
+z toward +x). The thesis draws one virtual camera in a mirrored frame (its x is our -x, and it names
halves after the mirrored image: its h_r / mu_3 ray is our left half's Ray 1); magnitudes agree.

The common FOV at depth Z is the overlap of the two wedges. Its type (Table 5.1) follows from the
coefficient epsilon = phi_4 / phi_2 (eq. 5.12): divergent (epsilon >= 1, the overlap is bounded by Ray 1
only), semi-divergent (0 <= epsilon < 1, Ray 2 takes over beyond the depth where it crosses Ray 1; still
open), convergent (epsilon < 0, finite: the overlap closes where the two Rays 2 meet on the axis).

These closed forms are exact 2D ray optics of an untilted prism (the thesis makes no small-angle
approximation in ch. 5); :mod:`prismstereo.analysis.fov_exact` traces the sensor row through the real
prism and reports the difference, which is ~1e-13 mm when the outer rays hit the prism and becomes the
truncation by the prism's edge (or total internal reflection) when they do not.

Thesis errata found while checking against the exact model (numbers for setup 1 unless stated):

* Eq. 5.36-5.37 pair Ray 1_l's angle mu_3 with h_l and mu_4 with h_r; by eq. 5.30-5.33 mu_3' gives h_r
  (the ray traced by :func:`prismstereo.geometry.optics.apex_ray` confirms it), so the intercepts are
  swapped: an error of |h_r - h_l| = 0.407 mm at d = 0 (5.10 mm for the 21.8 deg prism).
* Sec. 5.4.2 assumes Rays 2 unchanged by an x translation, but then gives their shift (eq. 5.34-5.35),
  which the exact model confirms (both Rays 2 move by -Delta v in our x; 0.0615 mm at d = 8 mm).
* Sec. 5.4.2 / Table 5.4 call the common FOV angle "constant" under x translation; it changes at second
  order: gamma = 0.107514 rad at d = 0 and 0.107714 rad at d = +-8 mm (+0.19 %), by the thesis' own
  eq. 5.27-5.31 and by ray tracing alike (they agree to 1e-16 rad).
* Sec. 5.4.1 / 6.3.3 say T_o leaves the common FOV unchanged. That holds where Ray 1 bounds it, but
  setup 1 is semi-divergent (alpha 6.4 deg > alpha_1 = 5.62 deg; the thesis calls it divergent), so beyond
  the Ray 1 / Ray 2 crossing (Z = 1.40 m at T_o = 170 mm, 1.73 m at 210 mm) Ray 2 bounds it and T_o
  matters: 2824 mm past the back plane (the thesis' prism-fixed frame) the common width is 262.0 mm at
  T_o = 170 mm and 269.7 mm at T_o = 210 mm (+2.9 %); before the crossing the widths are identical.
* Eq. 5.17-5.25 assume the sensor-edge ray hits the prism face. For the library's setup 2 (f 8 mm, the
  100 mm prism at T_o = 170 mm) it enters at |x| = 57.4 mm, past the 50 mm half-width: the true outer
  border is the prism's edge, and the closed form overestimates the common width past its Ray 1 / Ray 2
  crossing (675 mm): 473 mm vs the exact 329 mm at Z = 2.5 m. ``edge_rays_on_prism`` flags this.
* Table 5.3's v values follow eq. 5.25 with T_o = 200.55 mm (setups 1, 3; T = 5.6 mm) and 190.90 mm
  (setups 2, 4; T = 20.0 mm, i.e. b = 100 mm); the thesis does not state these T_o. One T_o fits both
  sensors only with T = 20.0 mm for the 21.8 deg prism (with its listed T = 5.6 mm the two sensors would
  need T_o = 181.53 and 186.10 mm), so the thesis itself used the consistent thickness.
* Case 2 of sec. 5.2.1 reads "phi_2 now becomes greater than phi_1"; it means phi_4.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch

from prismstereo.analysis._common import AnalysisError, as_tensor, check_rig, check_untilted, depths_beyond
from prismstereo.analysis.fov_formulas import (
    BoundaryAngles,
    _edge_inside,
    _edge_intercept,
    _exit_angle,
    boundary_angles,
    fov_type_from_epsilon,
    ray1_angle,
    ray2_angle,
)
from prismstereo.geometry.rig import BiPrismRig

__all__ = ["RayLine", "FOVClosedForm", "FOVExtent", "fov_closed_form", "fov_extent"]


class RayLine(NamedTuple):
    """A border ray in the top view: x(Z) = intercept + (Z - back_plane_z) tan(angle).

    Attributes:
        angle: () signed angle to the z axis (rad), positive toward +x.
        intercept: () x where the ray leaves the back plane (mm).
        back_plane_z: () depth of the back plane, T_o + T (mm).
    """

    angle: torch.Tensor
    intercept: torch.Tensor
    back_plane_z: torch.Tensor

    def x_at(self, depth: torch.Tensor | float) -> torch.Tensor:
        """x (mm) of the ray at camera depth Z (mm), broadcast over ``depth``."""
        depth = as_tensor(depth, self.angle, "depth")
        return self.intercept + (depth - self.back_plane_z) * torch.tan(self.angle)



class FOVClosedForm(NamedTuple):
    """The thesis' FOV description of a rig (eq. 5.1-5.37), in our frame.

    Attributes:
        phi2: () Ray 1 angle of the centred prism (eq. 5.5).
        phi4: () Ray 2 angle for the full sensor width l (eq. 5.9).
        gamma: () angle between the two Rays 1 (eq. 5.10 for d = 0; mu_3 + mu_4 of sec. 5.4.2 otherwise).
        epsilon: () phi4 / phi2 (eq. 5.12).
        fov_type: Table 5.1 type from epsilon.
        boundary: alpha_1, alpha_2 for this n, sensor width and f.
        h: () Ray 1 intercept of the centred prism, T tan(phi_2') (eq. 5.16 with b = 2 T / tan(alpha)).
        v: () Ray 2 intercept of the centred prism (eq. 5.25).
        left_ray1, left_ray2, right_ray1, right_ray2: the four border rays (with the offset d of eq.
            5.27-5.37 and each half's own edge pixel).
        crossing_depth: () depth where Ray 2 crosses Ray 1 (inf if they do not meet beyond the back plane).
        far_depth: () depth where a convergent common FOV closes (inf otherwise).
        edge_rays_on_prism: False if an edge ray misses the prism's face (Ray 2 is then not the border).
    """

    phi2: torch.Tensor
    phi4: torch.Tensor
    gamma: torch.Tensor
    epsilon: torch.Tensor
    fov_type: str
    boundary: BoundaryAngles
    h: torch.Tensor
    v: torch.Tensor
    left_ray1: RayLine
    left_ray2: RayLine
    right_ray1: RayLine
    right_ray2: RayLine
    crossing_depth: torch.Tensor
    far_depth: torch.Tensor
    edge_rays_on_prism: bool


class FOVExtent(NamedTuple):
    """What each half sees at depths Z (top view).

    Attributes:
        depth: (D,) depths (mm).
        left: (D, 2) [x_min, x_max] seen by the left (reference) half (mm).
        right: (D, 2) [x_min, x_max] seen by the right half.
        common: (D, 2) the overlap [max of minima, min of maxima]; meaningless where ``overlap`` is False.
        width: (D,) common-FOV width, 0 where the halves do not overlap.
        overlap: (D,) bool.
    """

    depth: torch.Tensor
    left: torch.Tensor
    right: torch.Tensor
    common: torch.Tensor
    width: torch.Tensor
    overlap: torch.Tensor

    @classmethod
    def from_halves(cls, depth: torch.Tensor, left: torch.Tensor, right: torch.Tensor) -> FOVExtent:
        """The extent whose halves see ``left`` and ``right`` (D, 2) at ``depth`` (D,): their overlap and width."""
        lo = torch.maximum(left[..., 0], right[..., 0])
        hi = torch.minimum(left[..., 1], right[..., 1])
        overlap = hi > lo
        return cls(depth, left, right, torch.stack([lo, hi], -1), (hi - lo).clamp_min(0), overlap)




# ----------------------------------------------------------------------------------- a rig's FOV
def fov_closed_form(rig: BiPrismRig) -> FOVClosedForm:
    """The thesis' closed-form FOV of a rig: angles, type, and the four border rays in our frame.

    Uses the rig's alpha, n, f, T, T_o, offset d (eq. 5.27-5.37) and, for each half's Ray 2, the distance
    from the principal point to that half's sensor edge (the thesis' l / 2 when the principal point is
    centred). h uses the rig's thickness (b = 2 T / tan(alpha) in eq. 5.16).

    Raises:
        AnalysisError: for a tilted prism (no closed form), or total internal reflection of a border ray.

    Example:
        >>> fov = fov_closed_form(thesis_setup1())
        >>> fov.fov_type, round(float(fov.left_ray1.intercept), 5)
        ('semi-divergent', 0.20344)
    """
    check_rig(rig)
    check_untilted(rig, "fov_closed_form")
    f64 = torch.float64
    alpha, n = torch.tensor(rig.alpha_rad, dtype=f64), torch.tensor(rig.refractive_index, dtype=f64)
    f, t = torch.tensor(rig.focal_length_mm, dtype=f64), torch.tensor(rig.prism_thickness_mm, dtype=f64)
    t_o, d = torch.tensor(rig.apex_distance_mm, dtype=f64), torch.tensor(rig.prism_offset_x_mm, dtype=f64)
    width = rig.image_width * rig.pixel_size_mm
    z_b = t_o + t
    phi2 = ray1_angle(alpha, n)
    phi4 = ray2_angle(alpha, n, width, f)
    epsilon = phi4 / phi2
    # Rays 1 with the offset (eq. 5.27-5.33); our left half's is the thesis' mu_3 / h_r ray.
    w0 = torch.atan(d / t_o)  # eq. 5.27
    mu3p = alpha - torch.asin(torch.sin(alpha - w0) / n)  # eq. 5.28, 5.30
    mu4p = torch.asin(torch.sin(alpha + w0) / n) - alpha  # eq. 5.29, 5.31
    left1 = RayLine(_exit_angle(mu3p, n, "Ray 1"), d + t * torch.tan(mu3p), z_b)  # eq. 5.33, 5.36 (corrected)
    right1 = RayLine(_exit_angle(mu4p, n, "Ray 1"), d + t * torch.tan(mu4p), z_b)  # eq. 5.32, 5.37 (corrected)
    # Rays 2 of each half's own edge pixel (u = -0.5 and u = W - 0.5), eq. 5.17-5.25, shifted by eq. 5.35.
    ta = torch.tan(alpha)
    half_width = t / ta
    rays2, on_prism = [], True
    for sign, edge_mm in ((-1.0, (rig.cx + 0.5) * rig.pixel_size_mm), (1.0, (rig.image_width - 0.5 - rig.cx)
                                                                         * rig.pixel_size_mm)):
        tan_w = torch.tensor(edge_mm / rig.focal_length_mm, dtype=f64)
        if edge_mm <= 0:
            raise AnalysisError("the principal point lies on the sensor edge: one half has no outer border")
        if bool(tan_w * ta >= 1):
            raise AnalysisError("an edge ray is parallel to the prism face (tan(omega) tan(alpha) >= 1)")
        inside = _edge_inside(alpha, n, tan_w)
        v_half, u_half = _edge_intercept(alpha, n, tan_w, t, t_o)
        shift = d * ta * (tan_w - torch.tan(inside)) / (1 - ta * tan_w)  # eq. 5.35
        entry = sign * u_half - d * ta * tan_w / (1 - ta * tan_w)  # entry x on the face, shifted by eq. 5.34
        on_prism = on_prism and bool((entry - d).abs() <= half_width)
        rays2.append(RayLine(sign * _exit_angle(inside, n, "Ray 2"), sign * v_half - shift, z_b))
    left2, right2 = rays2
    h = t * torch.tan(alpha - torch.asin(torch.sin(alpha) / n))
    v = _edge_intercept(alpha, n, torch.as_tensor(width / (2 * rig.focal_length_mm), dtype=f64), t, t_o)[0]
    crossing = torch.minimum(_meet(left1, right2), _meet(right1, left2))
    far = _meet(left2, right2)
    return FOVClosedForm(
        phi2=phi2, phi4=phi4, gamma=left1.angle - right1.angle, epsilon=epsilon,
        fov_type=fov_type_from_epsilon(float(epsilon)),
        boundary=boundary_angles(rig.refractive_index, width, rig.focal_length_mm),
        h=h, v=v, left_ray1=left1, left_ray2=left2, right_ray1=right1, right_ray2=right2,
        crossing_depth=crossing, far_depth=far, edge_rays_on_prism=on_prism,
    )


def _meet(a: RayLine, b: RayLine) -> torch.Tensor:
    """Depth where two lines meet beyond the back plane (inf if parallel or behind it)."""
    slope = torch.tan(a.angle) - torch.tan(b.angle)
    dz = (b.intercept - a.intercept) / torch.where(slope == 0, torch.ones_like(slope), slope)
    inf = torch.full_like(dz, math.inf)
    return torch.where((slope == 0) | (dz <= 0), inf, a.back_plane_z + dz)


def fov_extent(fov: FOVClosedForm, depth: torch.Tensor | float) -> FOVExtent:
    """The closed-form extents at depths Z: left half [Ray 2, Ray 1], right half [Ray 1, Ray 2], overlap.

    Args:
        fov: from :func:`fov_closed_form`.
        depth: (D,) or scalar depths (mm), beyond the back plane.

    Example:
        >>> ext = fov_extent(fov_closed_form(thesis_setup1()), [1000.0])
        >>> round(float(ext.width[0]), 2)
        89.13
    """
    depth = depths_beyond(depth, float(fov.left_ray1.back_plane_z)).to(fov.phi2.dtype)
    left = torch.stack([fov.left_ray2.x_at(depth), fov.left_ray1.x_at(depth)], -1)
    right = torch.stack([fov.right_ray1.x_at(depth), fov.right_ray2.x_at(depth)], -1)
    return FOVExtent.from_halves(depth, left, right)
