"""The closed forms of thesis chapter 5 as functions of the prism's and the camera's numbers.

Each half-image sees a wedge bounded by two rays leaving the prism's back plane (:mod:`prismstereo.analysis.fov`
draws them for a rig): **Ray 1**, the camera ray through the apex refracted by the half's face, at angle phi_2
(eq. 5.2-5.5) and back-plane intercept h (eq. 5.16); **Ray 2**, the refracted ray of the sensor's edge pixel, at
angle phi_4 (eq. 5.6-5.9) and intercept v (eq. 5.17-5.25). From these follow the angle gamma = 2 phi_2 between the
virtual optical axes (eq. 5.10), the coefficient of field of view epsilon = phi_4 / phi_2 (eq. 5.12), the FOV type
of Table 5.1 with the prism angles alpha_1 and alpha_2 where it changes, and the shift of the rays by an x
translation of the prism (eq. 5.34-5.35).

Angles are in radians, lengths in mm, for a centred, untilted prism (magnitudes; the signs of a rig's four rays
are :func:`~prismstereo.analysis.fov.fov_closed_form`'s). Inputs are numbers or broadcastable tensors
(differentiable); bad values and total internal reflection raise :class:`~prismstereo.analysis.AnalysisError`.
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

import torch

from prismstereo.analysis._common import AnalysisError, as_tensor, brent, check_positive

__all__ = [
    "FOVType",
    "FOV_TYPES",
    "BoundaryAngles",
    "ray1_angle",
    "ray2_angle",
    "ray1_intercept",
    "ray2_intercept",
    "common_fov_angle",
    "fov_coefficient",
    "fov_type",
    "fov_type_from_epsilon",
    "boundary_angles",
    "offset_shift",
]

FOVType = Literal["divergent", "semi-divergent", "convergent"]
FOV_TYPES: tuple[str, str, str] = ("divergent", "semi-divergent", "convergent")


class BoundaryAngles(NamedTuple):
    """Prism angles where the FOV type changes (Table 5.1), in radians.

    Attributes:
        alpha1: phi_4 = phi_2 (divergent below, semi-divergent above).
        alpha2: phi_4 = 0 (semi-divergent below, convergent above).
    """

    alpha1: float
    alpha2: float



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
