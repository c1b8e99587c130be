"""Field of view of the bi-prism system (thesis chapter 5): closed forms, and the exact FOV by ray tracing.

Every quantity is in the top view (the x-z plane of the camera frame, the sensor's centre row) like the
thesis' figures 5.3-5.7. Conventions (:mod:`prismstereo.conventions`): x right, z forward, mm, radians;
the left half-image (rays through the face at x < d) is the reference view.

Each half sees a wedge bounded by two rays leaving the back plane z_b = T_o + T:

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
from typing import Literal, NamedTuple

import torch

from prismstereo.analysis._common import (
    AnalysisError,
    as_tensor,
    brent,
    check_positive,
    check_rig,
    check_untilted,
    depths_beyond,
)
from prismstereo.geometry.rig import BiPrismRig

__all__ = [
    "FOVType",
    "FOV_TYPES",
    "RayLine",
    "BoundaryAngles",
    "FOVClosedForm",
    "FOVExtent",
    "ray1_angle",
    "ray2_angle",
    "ray1_intercept",
    "ray2_intercept",
    "common_fov_angle",
    "fov_coefficient",
    "fov_type",
    "boundary_angles",
    "offset_shift",
    "fov_closed_form",
    "fov_extent",
    "fov_type_from_epsilon",
    ]

FOVType = Literal["divergent", "semi-divergent", "convergent"]
FOV_TYPES: tuple[str, str, str] = ("divergent", "semi-divergent", "convergent")


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


class BoundaryAngles(NamedTuple):
    """Prism angles where the FOV type changes (Table 5.1), in radians.

    Attributes:
        alpha1: phi_4 = phi_2 (divergent below, semi-divergent above).
        alpha2: phi_4 = 0 (semi-divergent below, convergent above).
    """

    alpha1: float
    alpha2: float


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


def _check_prism(alpha: torch.Tensor, n: torch.Tensor) -> None:
    check_positive(n - 1.0, "refractive_index - 1")
    a = alpha.detach()
    if bool(((a <= 0) | (a >= math.pi / 2) | ~torch.isfinite(a)).any()):
        raise AnalysisError(f"alpha must be in (0, pi/2) rad, got {a.flatten()[0].item()!r}")


def _exit_angle(inside: torch.Tensor, n: torch.Tensor, what: str) -> torch.Tensor:
    """asin(n sin(inside)): refraction at the back plane, refusing total internal reflection."""
    s = n * torch.sin(inside)
    if bool((s.detach().abs() >= 1).any()):
        raise AnalysisError(f"{what} is totally internally reflected at the back plane (n sin = {s.max().item():.4f})")
    return torch.asin(s)


def ray1_angle(alpha: torch.Tensor | float, n: torch.Tensor | float) -> torch.Tensor:
    """phi_2: angle of Ray 1 (the refracted apex ray) to the back-plane normal (eq. 5.2-5.5).

    phi_2 = asin(n sin(alpha - asin(sin(alpha) / n))).

    Args:
        alpha: prism corner angle (rad), any shape.
        n: refractive index, broadcastable.

    Returns:
        phi_2 (rad), float64 for Python numbers, else the input's dtype.

    Raises:
        AnalysisError: alpha outside (0, pi/2), n <= 1, or total internal reflection.

    Example:
        >>> round(float(ray1_angle(math.radians(6.4), 1.48)), 5)   # Table 5.3
        0.05376
    """
    alpha = as_tensor(alpha, name="alpha")
    n = as_tensor(n, alpha, "n")
    _check_prism(alpha, n)
    return _exit_angle(alpha - torch.asin(torch.sin(alpha) / n), n, "Ray 1")


def _edge_inside(alpha: torch.Tensor, n: torch.Tensor, tan_omega: torch.Tensor) -> torch.Tensor:
    """phi_4' (eq. 5.8): angle of the edge ray inside the glass, positive away from the axis."""
    return torch.asin(torch.sin(torch.atan(tan_omega) + alpha) / n) - alpha


def ray2_angle(
    alpha: torch.Tensor | float,
    n: torch.Tensor | float,
    sensor_width_mm: torch.Tensor | float,
    focal_length_mm: torch.Tensor | float,
) -> torch.Tensor:
    """phi_4: angle of Ray 2 (the refracted sensor-edge ray) to the back-plane normal (eq. 5.6-5.9, 5.11).

    phi_4 = asin(n sin(asin(sin(omega + alpha) / n) - alpha)), omega = atan(l / 2f). Positive: the ray
    leaves away from the axis (the half's outer border diverges); negative: toward it (convergent).

    Args:
        alpha: prism angle (rad).
        n: refractive index.
        sensor_width_mm: sensor width l (mm).
        focal_length_mm: f (mm).

    Returns:
        phi_4 (rad), broadcast shape.

    Raises:
        AnalysisError: on invalid parameters or total internal reflection.

    Example:
        >>> round(float(ray2_angle(math.radians(21.8), 1.48, 4.7616, 25.0)), 5)   # Table 5.3, set-up 2
        -0.09785
    """
    alpha = as_tensor(alpha, name="alpha")
    n = as_tensor(n, alpha, "n")
    width = as_tensor(sensor_width_mm, alpha, "sensor_width_mm")
    f = as_tensor(focal_length_mm, alpha, "focal_length_mm")
    _check_prism(alpha, n)
    check_positive(width, "sensor_width_mm")
    check_positive(f, "focal_length_mm")
    return _exit_angle(_edge_inside(alpha, n, width / (2 * f)), n, "Ray 2")


def common_fov_angle(alpha: torch.Tensor | float, n: torch.Tensor | float) -> torch.Tensor:
    """gamma = 2 phi_2, the angle between the two virtual optical axes (eq. 5.10).

    Example:
        >>> round(math.degrees(float(common_fov_angle(math.radians(6.4), 1.48))), 3)
        6.16
    """
    return 2.0 * ray1_angle(alpha, n)


def fov_coefficient(
    alpha: torch.Tensor | float,
    n: torch.Tensor | float,
    sensor_width_mm: torch.Tensor | float,
    focal_length_mm: torch.Tensor | float,
) -> torch.Tensor:
    """epsilon = phi_4 / phi_2, the coefficient of field of view (eq. 5.12).

    Example:
        >>> round(float(fov_coefficient(math.radians(6.4), 1.48, 4.7616, 25.0)), 4)
        0.754
    """
    return ray2_angle(alpha, n, sensor_width_mm, focal_length_mm) / ray1_angle(alpha, n)


def fov_type_from_epsilon(epsilon: float) -> str:
    """The FOV type of Table 5.1 for a given epsilon = phi_4 / phi_2: 'divergent' (>= 1), 'semi-divergent'
    (>= 0) or 'convergent'.

    Example:
        >>> fov_type_from_epsilon(1.0), fov_type_from_epsilon(0.5), fov_type_from_epsilon(-0.1)
        ('divergent', 'semi-divergent', 'convergent')
    """
    if epsilon >= 1.0:
        return "divergent"
    return "semi-divergent" if epsilon >= 0.0 else "convergent"


def fov_type(alpha: float, n: float, sensor_width_mm: float, focal_length_mm: float) -> FOVType:
    """The FOV type of Table 5.1 from epsilon: 'divergent' (epsilon >= 1), 'semi-divergent'
    (0 <= epsilon < 1) or 'convergent' (epsilon < 0).

    Example:
        >>> fov_type(math.radians(6.4), 1.48, 4.7616, 25.0), fov_type(math.radians(21.8), 1.48, 4.7616, 25.0)
        ('semi-divergent', 'convergent')
    """
    return fov_type_from_epsilon(float(fov_coefficient(alpha, n, sensor_width_mm, focal_length_mm)))  # type: ignore[return-value]


def boundary_angles(n: float, sensor_width_mm: float, focal_length_mm: float) -> BoundaryAngles:
    """alpha_1 (phi_4 = phi_2) and alpha_2 (phi_4 = 0) of Table 5.1, in radians.

    alpha_2 is closed form: phi_4 = 0 when sin(omega + alpha) = n sin(alpha), i.e.
    tan(alpha_2) = sin(omega) / (n - cos(omega)). alpha_1 is the root of phi_4 - phi_2 in (0, alpha_2)
    (Brent's method, 1e-14 rad). The thesis' alpha_3 (upper end of case 3) is not defined in the text.

    Args:
        n: refractive index (> 1).
        sensor_width_mm: l (mm).
        focal_length_mm: f (mm).

    Example:
        >>> b = boundary_angles(1.48, 4.7616, 25.0)
        >>> round(math.degrees(b.alpha1), 2), round(math.degrees(b.alpha2), 2)
        (5.62, 11.07)
    """
    for name, value in (("n", n), ("sensor_width_mm", sensor_width_mm), ("focal_length_mm", focal_length_mm)):
        if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
            raise AnalysisError(f"{name} must be a positive number, got {value!r}")
    if n <= 1:
        raise AnalysisError(f"n must be > 1, got {n}")
    omega = math.atan(sensor_width_mm / (2 * focal_length_mm))
    alpha2 = math.atan(math.sin(omega) / (n - math.cos(omega)))

    def gap(a: float) -> float:
        return float(ray2_angle(a, n, sensor_width_mm, focal_length_mm) - ray1_angle(a, n))

    alpha1 = brent(gap, 1e-9, alpha2, xtol=1e-14)
    return BoundaryAngles(alpha1, alpha2)


# ----------------------------------------------------------------------------------- intercepts
def ray1_intercept(
    alpha: torch.Tensor | float, n: torch.Tensor | float, back_width_mm: torch.Tensor | float
) -> torch.Tensor:
    """h: x where Ray 1 leaves the back plane, h = (b/2) tan(alpha) tan(alpha - asin(sin(alpha)/n)) (eq. 5.16).

    (b/2) tan(alpha) is the thickness T of a prism whose back plane is b wide, so h = T tan(phi_2').

    Example:
        >>> round(float(ray1_intercept(math.radians(6.4), 1.48, 100.0)), 5)   # Table 5.3
        0.20375
    """
    alpha = as_tensor(alpha, name="alpha")
    n = as_tensor(n, alpha, "n")
    b = as_tensor(back_width_mm, alpha, "back_width_mm")
    _check_prism(alpha, n)
    check_positive(b, "back_width_mm")
    return b / 2 * torch.tan(alpha) * torch.tan(alpha - torch.asin(torch.sin(alpha) / n))


def _edge_intercept(alpha, n, tan_omega, thickness, apex_distance):
    """v of eq. 5.20-5.23 for an edge ray of slope tan(omega) (u: entry x, p: entry depth past the apex)."""
    k = tan_omega * torch.tan(alpha)
    u = apex_distance * tan_omega / (1 - k)  # eq. 5.21
    p = apex_distance * k / (1 - k)  # eq. 5.20
    return u + (thickness - p) * torch.tan(_edge_inside(alpha, n, tan_omega)), u


def ray2_intercept(
    alpha: torch.Tensor | float,
    n: torch.Tensor | float,
    sensor_width_mm: torch.Tensor | float,
    focal_length_mm: torch.Tensor | float,
    thickness_mm: torch.Tensor | float,
    apex_distance_mm: torch.Tensor | float,
) -> torch.Tensor:
    """v: x where Ray 2 leaves the back plane (eq. 5.17-5.25).

    v = T_o l / (2f - l tan(alpha)) + (2 f T - (T + T_o) l tan(alpha)) / (2f - l tan(alpha)) tan(phi_4').

    Example:
        >>> round(float(ray2_intercept(math.radians(6.4), 1.48, 4.7616, 25.0, 5.6, 170.0)), 4)
        16.4673
    """
    alpha = as_tensor(alpha, name="alpha")
    n = as_tensor(n, alpha, "n")
    width = as_tensor(sensor_width_mm, alpha, "sensor_width_mm")
    f = as_tensor(focal_length_mm, alpha, "focal_length_mm")
    t = as_tensor(thickness_mm, alpha, "thickness_mm")
    t_o = as_tensor(apex_distance_mm, alpha, "apex_distance_mm")
    _check_prism(alpha, n)
    for value, name in ((width, "sensor_width_mm"), (f, "focal_length_mm"), (t, "thickness_mm"),
                        (t_o, "apex_distance_mm")):
        check_positive(value, name)
    if bool((width * torch.tan(alpha) >= 2 * f).any()):
        raise AnalysisError("the edge ray is parallel to the prism face (l tan(alpha) >= 2 f)")
    return _edge_intercept(alpha, n, width / (2 * f), t, t_o)[0]


def offset_shift(
    alpha: torch.Tensor | float,
    n: torch.Tensor | float,
    sensor_width_mm: torch.Tensor | float,
    focal_length_mm: torch.Tensor | float,
    offset_mm: torch.Tensor | float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(Delta u, Delta v) of an x translation d of the prism (eq. 5.34-5.35).

    Delta u = d tan(a) tan(w) / (1 - tan(a) tan(w)), Delta v = d tan(a) (tan(w) - tan(phi_4')) / (1 - tan(a) tan(w)).
    In our frame both Rays 2 move by -Delta v in x (the left one outward, the right one inward for d > 0).

    Example:
        >>> round(float(offset_shift(math.radians(6.4), 1.48, 4.7616, 25.0, 8.0)[1]), 4)
        0.0615
    """
    alpha = as_tensor(alpha, name="alpha")
    n = as_tensor(n, alpha, "n")
    tan_w = as_tensor(sensor_width_mm, alpha, "sensor_width_mm") / (2 * as_tensor(focal_length_mm, alpha))
    d = as_tensor(offset_mm, alpha, "offset_mm")
    _check_prism(alpha, n)
    ta = torch.tan(alpha)
    du = d * ta * tan_w / (1 - ta * tan_w)
    dv = d * ta * (tan_w - torch.tan(_edge_inside(alpha, n, tan_w))) / (1 - ta * tan_w)
    return du, dv


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
