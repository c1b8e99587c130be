"""Variable-parameter design (thesis sec. 6.3): the f, alpha, T or T_o that meets a target depth error.

The thesis' design equation is eq. 6.36, the disparity error term of eq. 6.22:
dZ = (Z - T (n - 1)/n)^2 / (T_o (n - 1) 2 alpha f) dD, solved for

* f (eq. 6.39), and the pixel count a sensor needs to keep the field of view at that focal length
  (eq. 6.40-6.41; :func:`required_pixels`);
* the prism thickness T at a fixed back-plane half-width t_b, with alpha = T / t_b (eq. 6.42-6.46; the
  root T^- is kept and T^+ rejected, :func:`required_thickness`);
* the prism distance T_o (eq. 6.47, :func:`required_apex_distance`).

:func:`design` also solves the same problem on the exact ray-traced model (Brent's method on the exact
dZ/dD of :func:`prismstereo.analysis.error.exact_dz_dd`) and reports the difference, and the exact error
of the thesis' design.

Units: the thesis drops dD from eq. 6.39, 6.44 and 6.47 ("assume dD ~ 1 pixel"), which mixes mm and
pixels; we keep dD = disparity_px * pixel_size (mm) so every length is in mm. The thesis' T^+ rejection
(fig. 6.10) is explained by the quadratic itself: T^+ T^- = (n Z / (n - 1))^2, so T^+ >= n Z / (n - 1) > Z:
the prism would reach past the object.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Literal, NamedTuple

import torch

from prismstereo.analysis._common import AnalysisError, brent
from prismstereo.analysis.error import ErrorCurves, closed_form_sensitivities, exact_dz_dd
from prismstereo.errors import PrismStereoError, check_option
from prismstereo.geometry.rig import BiPrismRig

__all__ = [
    "Vary",
    "VARY",
    "PixelDesign",
    "ThicknessDesign",
    "Design",
    "closed_form_error",
    "required_focal_length",
    "required_pixels",
    "required_thickness",
    "required_apex_distance",
    "design",
    "error_curves_of",
]

Vary = Literal["f", "alpha", "T_o", "T"]
VARY: tuple[str, ...] = ("f", "alpha", "T_o", "T")
_UNITS = {"f": "mm", "alpha": "deg", "T_o": "mm", "T": "mm"}


class PixelDesign(NamedTuple):
    """Eq. 6.39-6.41. focal_length_mm / focal_length_px needed, theta_vc (rad) and aspect a = h / v used,
    width_px x height_px the sensor (h = 2 f tan(theta_vc)), pixels = h v / 2 (one half-image, eq. 6.41)."""

    focal_length_mm: float
    focal_length_px: float
    theta_vc: float
    aspect: float
    width_px: float
    height_px: float
    pixels: float


class ThicknessDesign(NamedTuple):
    """Eq. 6.44-6.46. thickness = T^- (mm), rejected = T^+ (mm, > n Z / (n - 1)), alpha = T^- / t_b (rad,
    eq. 6.42), half_width = t_b (mm)."""

    thickness: float
    rejected: float
    alpha: float
    half_width: float


class Design(NamedTuple):
    """A variable-parameter design.

    Attributes:
        vary: 'f', 'alpha', 'T_o' or 'T'.
        unit: unit of the values ('mm' or 'deg').
        current: the rig's value.
        closed_form: the thesis' value (eq. 6.39, 6.42 + 6.46, 6.46, 6.47).
        exact: the value that meets the target on the exact model.
        difference: closed_form - exact.
        target_error_mm, depth_mm, disparity_px: the request.
        current_error: (closed form, exact) error of the current rig at depth_mm (mm).
        closed_form_error_exact: the exact error of the closed-form design at depth_mm (mm).
        closed_form_rig, exact_rig: the designed rigs (None if the value gives no valid rig).
        pixels: eq. 6.41 for vary='f', else None.
    """

    vary: str
    unit: str
    current: float
    closed_form: float
    exact: float
    difference: float
    target_error_mm: float
    depth_mm: float
    disparity_px: float
    current_error: tuple[float, float]
    closed_form_error_exact: float
    closed_form_rig: BiPrismRig | None
    exact_rig: BiPrismRig | None
    pixels: PixelDesign | None


def _check_request(rig: BiPrismRig, depth_mm: float, target_error_mm: float, disparity_px: float) -> None:
    if not isinstance(rig, BiPrismRig):
        raise AnalysisError(f"rig must be a BiPrismRig, got {type(rig).__name__}")
    for name, value in (("depth_mm", depth_mm), ("target_error_mm", target_error_mm), ("disparity_px", disparity_px)):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
            raise AnalysisError(f"{name} must be a positive number, got {value!r}")
    if depth_mm <= rig.apex_distance_mm + rig.prism_thickness_mm:
        back = rig.apex_distance_mm + rig.prism_thickness_mm
        raise AnalysisError(f"depth_mm must be beyond the prism's back plane ({back:g} mm), got {depth_mm}")


def _k(rig: BiPrismRig) -> float:
    return (rig.refractive_index - 1) / rig.refractive_index


def closed_form_error(rig: BiPrismRig, depth_mm: float, disparity_px: float = 1.0) -> float:
    """Eq. 6.36: dZ = (Z - T (n - 1)/n)^2 dD / (T_o (n - 1) 2 alpha f), dD = disparity_px * pixel size (mm).

    Example:
        >>> round(closed_form_error(thesis_setup1(), 1000.0), 3)
        10.166
    """
    _check_request(rig, depth_mm, 1.0, disparity_px)
    n = rig.refractive_index
    num = (depth_mm - rig.prism_thickness_mm * _k(rig)) ** 2 * disparity_px * rig.pixel_size_mm
    return num / (rig.apex_distance_mm * (n - 1) * 2 * rig.alpha_rad * rig.focal_length_mm)


def required_focal_length(rig: BiPrismRig, depth_mm: float, target_error_mm: float, disparity_px: float = 1.0) -> float:
    """Eq. 6.39: f = (Z - T (n - 1)/n)^2 dD / (T_o (n - 1) 2 alpha dZ) (mm; dD in mm).

    Example:
        >>> round(required_focal_length(thesis_setup1(), 1000.0, 10.0), 3)
        25.415
    """
    _check_request(rig, depth_mm, target_error_mm, disparity_px)
    return rig.focal_length_mm * closed_form_error(rig, depth_mm, disparity_px) / target_error_mm


def required_pixels(
    rig: BiPrismRig, depth_mm: float, target_error_mm: float, disparity_px: float = 1.0, theta_vc: float | None = None
) -> PixelDesign:
    """Eq. 6.40-6.41: the pixel count that meets the target at a fixed field of view.

    With the focal length in pixels f_px from eq. 6.39 (dD = disparity_px pixels), h = 2 f_px tan(theta_vc)
    (eq. 6.37), v = h / a (eq. 6.38) and pixels = h v / 2 = 2 f_px^2 tan^2(theta_vc) / a (eq. 6.40-6.41).
    The thesis' eq. 6.37 makes h/2 = f tan(theta_vc) the half sensor, so theta_vc defaults to the real
    camera's half angle atan(l / 2f) (the rig's field of view is kept) and h v / 2 is one half-image; for
    the rig itself this gives W H / 2.

    Example:
        >>> rig = thesis_setup1()
        >>> d = required_pixels(rig, 1000.0, closed_form_error(rig, 1000.0))   # the rig's own error
        >>> round(d.width_px), round(d.pixels)
        (1024, 393216)
    """
    _check_request(rig, depth_mm, target_error_mm, disparity_px)
    if theta_vc is None:
        theta_vc = math.atan(rig.image_width * rig.pixel_size_mm / (2 * rig.focal_length_mm))
    if not 0 < theta_vc < math.pi / 2:
        raise AnalysisError(f"theta_vc must be in (0, pi/2) rad, got {theta_vc}")
    aspect = rig.image_width / rig.image_height
    f_px = required_focal_length(rig, depth_mm, target_error_mm, disparity_px) / rig.pixel_size_mm
    width = 2 * f_px * math.tan(theta_vc)
    return PixelDesign(f_px * rig.pixel_size_mm, f_px, theta_vc, aspect, width, width / aspect,
                       2 * f_px**2 * math.tan(theta_vc) ** 2 / aspect)


def required_thickness(
    rig: BiPrismRig,
    depth_mm: float,
    target_error_mm: float,
    disparity_px: float = 1.0,
    half_width_mm: float | None = None,
) -> ThicknessDesign:
    """Eq. 6.43-6.46: the prism thickness (and angle alpha = T / t_b, eq. 6.42) meeting the target.

    T^2 - 2 P T + (n Z / (n - 1))^2 = 0 with P = n Z / (n - 1) + n^2 T_o f dZ / ((n - 1) t_b dD);
    T^- = P - sqrt(P^2 - (n Z / (n - 1))^2) is kept (eq. 6.46), T^+ (eq. 6.45) rejected.

    Args:
        rig: the rig.
        depth_mm: Z.
        target_error_mm: dZ.
        disparity_px: dD in pixels.
        half_width_mm: t_b, default the rig's back-plane half-width T / tan(alpha).

    Example:
        >>> d = required_thickness(thesis_setup1(), 1000.0, 10.0)
        >>> round(d.thickness, 3), round(math.degrees(d.alpha), 3)
        (5.669, 6.506)
    """
    _check_request(rig, depth_mm, target_error_mm, disparity_px)
    tb = rig.prism_width_mm / 2 if half_width_mm is None else float(half_width_mm)
    if not math.isfinite(tb) or tb <= 0:
        raise AnalysisError(f"half_width_mm must be > 0, got {half_width_mm!r}")
    n, k = rig.refractive_index, _k(rig)
    dd = disparity_px * rig.pixel_size_mm
    c = depth_mm / k
    p = c + n**2 * rig.apex_distance_mm * rig.focal_length_mm * target_error_mm / ((n - 1) * tb * dd)
    root = math.sqrt(p * p - c * c)
    t_plus = p + root  # eq. 6.45
    t_minus = c * c / t_plus  # eq. 6.46, P - sqrt(P^2 - c^2) written without cancellation
    return ThicknessDesign(t_minus, t_plus, t_minus / tb, tb)


def required_apex_distance(
    rig: BiPrismRig, depth_mm: float, target_error_mm: float, disparity_px: float = 1.0
) -> float:
    """Eq. 6.47: T_o = (Z - T (n - 1)/n)^2 dD / ((n - 1) 2 alpha f dZ) (mm).

    Example:
        >>> round(required_apex_distance(thesis_setup1(), 1000.0, 10.0), 2)
        172.82
    """
    _check_request(rig, depth_mm, target_error_mm, disparity_px)
    return rig.apex_distance_mm * closed_form_error(rig, depth_mm, disparity_px) / target_error_mm


# ----------------------------------------------------------------------------------- exact solver
def _with_value(rig: BiPrismRig, vary: str, value: float, half_width: float) -> BiPrismRig:
    if vary == "f":
        return rig.replace(focal_length_mm=value)
    if vary == "T_o":
        return rig.replace(apex_distance_mm=value)
    if vary == "T":
        return rig.replace(prism_thickness_mm=value, alpha_deg=math.degrees(math.atan(value / half_width)))
    return rig.replace(alpha_deg=value, prism_thickness_mm=half_width * math.tan(math.radians(value)))


def _params_with(rig: BiPrismRig, vary: str, value: float, half_width: float):
    p = rig.parameters(dtype=torch.float64)
    t = lambda x: torch.tensor(x, dtype=torch.float64)  # noqa: E731
    if vary == "f":
        return p._replace(f=t(value))
    if vary == "T_o":
        return p._replace(T_o=t(value))
    if vary == "T":
        return p._replace(T=t(value), alpha=t(math.atan(value / half_width)))
    a = math.radians(value)
    return p._replace(alpha=t(a), T=t(half_width * math.tan(a)))


def _exact_error(rig: BiPrismRig, vary: str, value: float, half_width: float, depth: float, dd_mm: float,
                 lateral: float) -> float:
    p = _params_with(rig, vary, value, half_width)
    return abs(float(exact_dz_dd(p, [depth], lateral)[0])) * dd_mm


def _solve_exact(rig, vary, start, half_width, depth, target, dd_mm, lateral) -> float:
    """Root of log(exact error / target) in the parameter (the error falls as f, alpha, T, T_o grow)."""
    cap = 60.0 if vary == "alpha" else math.inf

    def g(x: float) -> float:
        return math.log(_exact_error(rig, vary, x, half_width, depth, dd_mm, lateral) / target)

    lo = hi = min(start, 0.999 * cap)
    try:  # bracket the root
        value = g(lo)
        steps, grow = 0, value > 0
        while grow and value > 0:  # error too large: grow the parameter
            steps += 1
            if hi >= 0.999 * cap or steps > 100:
                raise AnalysisError(f"no {vary} up to {hi:g} {_UNITS[vary]} reaches {target} mm at {depth} mm")
            lo, hi = hi, min(hi * 1.25, 0.999 * cap)
            value = g(hi)
        while not grow and value < 0:  # error smaller than needed: shrink the parameter
            steps += 1
            if steps > 100:
                raise AnalysisError(f"no {vary} reaches {target} mm at {depth} mm on the exact model")
            hi, lo = lo, lo / 1.25
            value = g(lo)
    except PrismStereoError as exc:
        raise AnalysisError(f"no {vary} reaches {target} mm at {depth} mm on the exact model: {exc}") from exc
    if lo == hi:
        return lo
    return math.exp(brent(lambda s: g(math.exp(s)), math.log(lo), math.log(hi), xtol=1e-13))


def design(
    rig: BiPrismRig,
    *,
    target_error_mm: float,
    depth_mm: float,
    vary: Vary,
    disparity_px: float = 1.0,
    lateral_mm: float = 0.0,
) -> Design:
    """The value of one parameter that makes the depth error of a disparity error equal the target.

    Closed form by the thesis (eq. 6.39 for f, 6.46 with 6.42 for alpha, 6.46 for T, 6.47 for T_o) and
    exact by root finding on the ray-traced model (the point (lateral_mm, 0, Z), left pixel fixed, right
    pixel moved by disparity_px). Varying alpha or T keeps the back-plane half-width t_b (thesis sec.
    6.3.2: T = t_b tan(alpha)); varying f keeps the pixel pitch (zoom; eq. 6.41 gives the pixel count of
    keeping the field of view instead).

    Args:
        rig: the current rig.
        target_error_mm: wanted absolute depth error dZ at depth_mm.
        depth_mm: Z.
        vary: 'f', 'alpha', 'T_o' or 'T'.
        disparity_px: dD in pixels.
        lateral_mm: x of the design point.

    Raises:
        AnalysisError: bad input, or no value of the parameter meets the target on the exact model.

    Example:
        >>> d = design(thesis_setup1(), target_error_mm=10.0, depth_mm=1000.0, vary="T_o")
        >>> round(d.closed_form, 2), round(d.exact, 2)
        (172.82, 169.8)
    """
    check_option(vary, VARY, "vary")
    _check_request(rig, depth_mm, target_error_mm, disparity_px)
    if not math.isfinite(lateral_mm):
        raise AnalysisError(f"lateral_mm must be finite, got {lateral_mm!r}")
    half_width = rig.prism_width_mm / 2
    dd_mm = disparity_px * rig.pixel_size_mm
    pixels = None
    if vary == "f":
        current, closed = rig.focal_length_mm, required_focal_length(rig, depth_mm, target_error_mm, disparity_px)
        pixels = required_pixels(rig, depth_mm, target_error_mm, disparity_px)
    elif vary == "T_o":
        current, closed = rig.apex_distance_mm, required_apex_distance(rig, depth_mm, target_error_mm, disparity_px)
    else:
        thick = required_thickness(rig, depth_mm, target_error_mm, disparity_px, half_width)
        if vary == "T":
            current, closed = rig.prism_thickness_mm, thick.thickness
        else:  # alpha = T^- / t_b (eq. 6.42, small angle), in degrees
            current, closed = rig.alpha_deg, math.degrees(thick.alpha)
    exact = _solve_exact(rig, vary, closed, half_width, depth_mm, target_error_mm, dd_mm, lateral_mm)
    current_err = (closed_form_error(rig, depth_mm, disparity_px),
                   _exact_error(rig, vary, current, half_width, depth_mm, dd_mm, lateral_mm))
    try:
        closed_err = _exact_error(rig, vary, closed, half_width, depth_mm, dd_mm, lateral_mm)
    except PrismStereoError:
        closed_err = math.nan
    rigs = []
    for value in (closed, exact):
        try:
            rigs.append(_with_value(rig, vary, value, half_width))
        except PrismStereoError:
            rigs.append(None)
    return Design(vary, _UNITS[vary], current, closed, exact, closed - exact, float(target_error_mm),
                  float(depth_mm), float(disparity_px), current_err, closed_err, rigs[0], rigs[1], pixels)


def error_curves_of(
    rigs: Mapping[str, BiPrismRig], depth: torch.Tensor | Sequence[float], disparity_px: float = 1.0
) -> dict[str, ErrorCurves]:
    """Error-against-depth curves of several rigs (e.g. a rig and its designs; thesis fig. 6.12-6.14).

    Like :func:`prismstereo.analysis.error.error_curves`, but a depth at which a rig's axis point is not
    seen by both halves (past a convergent FOV) gets NaN in ``exact`` instead of an error.

    Args:
        rigs: name -> rig.
        depth: (D,) depths (mm).
        disparity_px: dD in pixels.

    Returns:
        name -> ErrorCurves(depth, closed_form, exact) in mm.

    Example:
        >>> curves = error_curves_of({"setup 1": thesis_setup1()}, [500.0, 1000.0])
        >>> [round(v, 2) for v in curves["setup 1"].exact.tolist()]
        [2.5, 9.99]
    """
    z = torch.as_tensor(depth, dtype=torch.float64).reshape(-1)
    if not math.isfinite(disparity_px) or disparity_px <= 0:
        raise AnalysisError(f"disparity_px must be > 0, got {disparity_px!r}")
    out = {}
    for name, rig in rigs.items():
        back = rig.apex_distance_mm + rig.prism_thickness_mm
        if z.numel() == 0 or bool((~torch.isfinite(z) | (z <= back)).any()):
            raise AnalysisError(f"depths must be beyond the back plane of rig {name!r} ({back:g} mm)")
        step = disparity_px * rig.pixel_size_mm
        closed = closed_form_sensitivities(rig, z).D.abs() * step
        exact = torch.full_like(z, math.nan)
        for i, zi in enumerate(z.tolist()):
            try:
                exact[i] = exact_dz_dd(rig, [zi]).abs()[0] * step
            except AnalysisError:
                pass  # not seen by both halves: NaN
        out[name] = ErrorCurves(z, closed, exact)
    return out
