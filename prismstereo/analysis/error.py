"""Depth from disparity and its error budget (thesis chapter 6, sec. 6.1-6.2), next to the exact model.

**Disparity.** For a scene point with images at columns u_l (left, reference half) and u_r (right half),
D = x_r - x_l = (u_r - u_l) * pixel_size in mm, with x = (u - cx) * pixel_size the sensor coordinate. It
is the thesis' D = x_l + x_r (eq. 6.14), written in our frame (the thesis' x_l is mirrored). D is
positive, grows with depth and tends to 2 f tan(omega_inf) for a point at infinity on the axis (omega_inf
the camera-ray angle that leaves the prism parallel to the axis), ~= 2 f (n - 1) alpha, the asymptote of
eq. 6.15 (0.85 % lower for setup 1). Exactly, :func:`project_pair` gives u_l
and u_r of a point through :func:`prismstereo.geometry.projection.project_points`, and :func:`depth_exact`
turns a pixel pair back into a depth by intersecting the two traced rays.

**Three depth models.** :func:`depth_small_angle` is eq. 6.15 (small alpha, small field angles);
:func:`depth_planar` is the general form (eq. 6.2-6.9: exact trigonometry of the top view, so exact for
points on the principal row of an untilted prism, and blind to y); :func:`depth_exact` traces rays in 3D.

**Sensitivities.** :func:`closed_form_sensitivities` gives the thesis' dZ/dD, dZ/dT_o, dZ/dalpha, dZ/df,
dZ/dn (eq. 6.20-6.35, in their depth forms 6.22, 6.25, 6.28, 6.31, 6.34) and dZ/dT (not written in the
thesis; (n - 1) / n from eq. 6.15). :func:`exact_sensitivities` differentiates the exact model with
autograd at fixed pixels. :func:`error_budget` combines either with parameter uncertainties (fig. 6.5
defaults) into absolute and relative depth errors (eq. 6.17-6.18).

Thesis errata, each with its size by the exact model (setup 1: alpha 6.4 deg, n 1.48, f 25 mm, T 5.6 mm, T_o 170 mm):

* Eq. 6.33/6.34 (dZ/dn) end in -T_o / n^2; differentiating eq. 6.15 gives +(T_o + T) / n^2 (the n
  dependence of A = (T_o + T)(n - 1)/n). The printed form is off by (2 T_o + T) / n^2 = 157.8 mm per unit
  n (1.6 mm for dn = 0.01), 1.6 % of dZ/dn at 1 m. ``n_form='thesis'`` reproduces the printed one.
* Eq. 6.27 prints (D + 2 alpha f^2) for (D + 2 alpha f)^2 (6.28 is right).
* Eq. 6.7 uses (T_o + T) tan(w) tan(a) / (1 - tan(w) tan(a)) for the depth of the entry point past the
  apex; it is T_o tan(w) tan(a) / (1 - ...) (eq. 6.6's first term, (T_o + T) instead of T_o, is wrong too).
  The printed version moves the depth by 0.019 mm at 1 m (2e-5): harmless.
* Eq. 6.9 as printed substitutes x/f for atan(x/f) inside the sines and has unbalanced terms; we implement
  the general form from eq. 6.2-6.8 with the corrections above (exact to 4e-15 on the principal row). The
  x/f substitution alone costs 0.27 % of depth at 1 m on the axis, 0.63 % 30 mm off it, 0.80 % at 2 m.
* Eq. 6.15 is a small-angle result and its error grows with depth (the denominator D - 2 f alpha (n - 1)
  vanishes at infinity while the exact limit of D is 0.85 % higher for alpha = 6.4 deg): on the axis of
  setup 1 it exceeds 1 % beyond Z = 562 mm (492 mm somewhere within 90 % of the common FOV) and reaches
  3.0 % at 1 m, 8.6 % at 2 m, 14.8 % at 3 m (see :func:`small_angle_check`); from Z = 20.0 m on, the
  exact disparity passes the asymptote and eq. 6.15 returns negative depths.
* Sec. 6.1 deduction 4 (the n error is range independent) and fig. 6.6 (overall relative error 2-4 %)
  contradict eq. 6.34-6.35: with Table 6.1 (T_o 210 mm) and the fig. 6.5 uncertainties the dn = 0.01 term
  alone is 2.8 % of depth at 0.5 m, 7.8 % at 1 m, 17.7 % at 2 m, and eq. 6.17 sums to 5.5 %, 14.0 %,
  30.9 % (the exact model agrees within 1 %); the 1 px disparity term is 0.41 %, 0.82 %, 1.65 %.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal, NamedTuple

import torch

from prismstereo.analysis._common import AnalysisError, as_tensor
from prismstereo.analysis.depth_models import (
    StereoPair,
    depth_constants,
    depth_exact,
    depth_planar,
    depth_small_angle,
    project_pair,
)
from prismstereo.analysis.fov_exact import exact_fov_extent
from prismstereo.errors import check_option
from prismstereo.geometry.parameters import RigParameters
from prismstereo.geometry.rig import BiPrismRig, as_parameters

__all__ = [
    "Sensitivities",
    "Uncertainties",
    "ErrorBudget",
    "SmallAngleCheck",
    "ErrorCurves",
    "closed_form_sensitivities",
    "exact_sensitivities",
    "exact_dz_dd",
    "error_budget",
    "small_angle_check",
    "error_curves",
]

NForm = Literal["corrected", "thesis"]
Model = Literal["closed_form", "exact"]


class Sensitivities(NamedTuple):
    """Partial derivatives of depth Z (each (D,)): D in mm/mm (disparity in mm), T_o and f and T in mm/mm,
    alpha in mm/rad, n in mm per unit index."""

    D: torch.Tensor
    T_o: torch.Tensor
    alpha: torch.Tensor
    f: torch.Tensor
    n: torch.Tensor
    T: torch.Tensor


@dataclasses.dataclass(frozen=True, kw_only=True)
class Uncertainties:
    """Parameter uncertainties for the error budget; defaults are the thesis' fig. 6.5 (and 6.3: 1 px).

    Args:
        disparity_px: dD in pixels (multiplied by the pixel size).
        focal_length_mm: df.
        alpha_rad: dalpha.
        apex_distance_mm: dT_o.
        refractive_index: dn.
        thickness_mm: dT (not in the thesis' figures; default 0).

    Raises:
        AnalysisError: on a negative or non-finite value.
    """

    disparity_px: float = 1.0
    focal_length_mm: float = 0.1
    alpha_rad: float = 0.001
    apex_distance_mm: float = 1.0
    refractive_index: float = 0.01
    thickness_mm: float = 0.0

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise AnalysisError(f"uncertainty {field.name} must be a finite number >= 0, got {value!r}")
            object.__setattr__(self, field.name, float(value))


class ErrorBudget(NamedTuple):
    """Depth error from parameter uncertainties (eq. 6.17-6.18), each (D,) in mm unless noted.

    Attributes:
        depth: Z.
        sensitivities: the partial derivatives used.
        contributions: |dZ/dp| * dp per parameter (same fields as Sensitivities).
        total: sum of the contributions (eq. 6.17, worst case).
        rss: root sum of squares (independent errors).
        relative: total / Z (eq. 6.18; fraction, not percent).
    """

    depth: torch.Tensor
    sensitivities: Sensitivities
    contributions: Sensitivities
    total: torch.Tensor
    rss: torch.Tensor
    relative: torch.Tensor


class SmallAngleCheck(NamedTuple):
    """Relative depth errors of eq. 6.15 and of the planar general form against exact points.

    Attributes:
        depth: (D,) true depths (mm).
        lateral: (D, K) x of the test points (mm), spread over the exact common FOV.
        error_small_angle: (D, K) (Z_6.15 - Z) / Z.
        error_planar: (D, K) (Z_6.9 - Z) / Z.
        valid: (D, K) both halves see the point.
        threshold: the relative error tested.
        first_depth_over: smallest depth where some valid |error_small_angle| > threshold (nan if none).
    """

    depth: torch.Tensor
    lateral: torch.Tensor
    error_small_angle: torch.Tensor
    error_planar: torch.Tensor
    valid: torch.Tensor
    threshold: float
    first_depth_over: float


class ErrorCurves(NamedTuple):
    """Absolute depth error of a disparity error (fig. 6.3 style): depth (D,), closed_form (D,) by eq.
    6.22 / 6.36, exact (D,) by the exact model, both in mm."""

    depth: torch.Tensor
    closed_form: torch.Tensor
    exact: torch.Tensor


# ----------------------------------------------------------------------------------- sensitivities
def _depths(depth: torch.Tensor | float) -> torch.Tensor:
    z = as_tensor(depth, name="depth").reshape(-1)
    if z.numel() == 0 or bool((~torch.isfinite(z) | (z <= 0)).any()):
        raise AnalysisError("depths must be finite and positive (mm)")
    return z


def closed_form_sensitivities(
    rig: BiPrismRig | RigParameters, depth: torch.Tensor | float, n_form: NForm = "corrected"
) -> Sensitivities:
    """The thesis' closed-form partial derivatives of depth at depth Z (eq. 6.20-6.35, depth forms).

    With A = (T_o + T)(n - 1)/n, B = T_o (n - 1)/n, G = (Z - A)/B and R = (Z - A + B)/(Z - A):
    dZ/dD = (Z - A + B)^2 / (2 alpha f n B) (6.22); dZ/dT_o = (n - 1)/n (G + 1) (6.25);
    dZ/dalpha = -B G^2 (R/alpha - R^2/(n alpha)) (6.28); dZ/df = -B G^2 (R/f - R^2/(n f)) (6.31);
    dZ/dn = T_o G / n^2 - B G^2 R / n + (T_o + T)/n^2 (6.34 corrected; 'thesis': - T_o/n^2);
    dZ/dT = (n - 1)/n (from 6.15). The disparity forms (6.20, 6.24, 6.27, 6.30, 6.33) are the same
    functions after substituting eq. 6.15.

    Args:
        rig: rig or tensors.
        depth: (D,) or scalar Z (mm); sets the dtype.
        n_form: 'corrected' (derivative of eq. 6.15) or 'thesis' (eq. 6.34 as printed).

    Returns:
        Sensitivities of shape (D,).

    Example:
        >>> s = closed_form_sensitivities(thesis_setup1(), [1000.0])
        >>> round(float(s.D[0]), 1)   # mm of depth per mm of disparity
        2186.3
    """
    check_option(n_form, ("corrected", "thesis"), "n_form")
    z = _depths(depth)
    p = as_parameters(rig, z)
    a, b = depth_constants(p)
    g, r = (z - a) / b, (z - a + b) / (z - a)
    k = (p.n - 1) / p.n
    dd = (z - a + b) ** 2 / (2 * p.alpha * p.f * p.n * b)  # eq. 6.22
    dto = k * (g + 1)  # eq. 6.25
    dalpha = -b * g**2 * (r / p.alpha - r**2 / (p.n * p.alpha))  # eq. 6.28
    df = -b * g**2 * (r / p.f - r**2 / (p.n * p.f))  # eq. 6.31
    last = (p.T_o + p.T) / p.n**2 if n_form == "corrected" else -p.T_o / p.n**2
    dn = p.T_o / p.n**2 * g - b / p.n * g**2 * r + last  # eq. 6.34
    dt = k * torch.ones_like(z)
    return Sensitivities(dd, dto, dalpha, df, dn, dt)


def _exact_pixels(p: RigParameters, depth: torch.Tensor, lateral: torch.Tensor) -> StereoPair:
    points = torch.stack([lateral.expand_as(depth), torch.zeros_like(depth), depth], -1)
    with torch.no_grad():
        pair = project_pair(RigParameters(**{k: (v.detach() if isinstance(v, torch.Tensor) else v)
                                             for k, v in p._asdict().items()}), points)
    bad = ~pair.valid
    if bool(bad.any()):
        raise AnalysisError(
            f"the point (x={float(lateral):g}, y=0, Z={float(depth[bad][0]):g} mm) is not seen by both halves "
            "(outside the common FOV)"
        )
    return pair


def exact_dz_dd(rig: BiPrismRig | RigParameters, depth: torch.Tensor | float, lateral_mm: float = 0.0) -> torch.Tensor:
    """Exact dZ/dD (mm/mm) at points (lateral_mm, 0, Z): the left (reference) pixel fixed, the right one moved.

    Example:
        >>> round(float(exact_dz_dd(thesis_setup1(), [1000.0])[0]), 1)
        2148.0
    """
    z = _depths(depth)
    p = as_parameters(rig, z)
    pair = _exact_pixels(p, z, as_tensor(lateral_mm, z, "lateral_mm"))
    uv_r = pair.uv_right.detach().clone().requires_grad_(True)
    with torch.enable_grad():
        zz = depth_exact(p, pair.uv_left.detach(), uv_r).depth
        (grad,) = torch.autograd.grad(zz.sum(), uv_r)
    return grad[..., 0].detach() / p.pixel_size.detach()


def exact_sensitivities(
    rig: BiPrismRig | RigParameters, depth: torch.Tensor | float, lateral_mm: float = 0.0
) -> Sensitivities:
    """Partial derivatives of the exact depth at points (lateral_mm, 0, Z), by autograd.

    The point is projected into both halves (:func:`project_pair`); with those pixels held fixed, the
    depth of their traced rays' intersection (:func:`depth_exact`) is differentiated w.r.t. the right
    pixel's column (dZ/dD = dZ/du_r / pixel_size: the reference pixel stays, the match moves) and w.r.t.
    each rig parameter. These are the exact counterparts of :func:`closed_form_sensitivities`.

    Args:
        rig: rig or tensors (d and tilt are honoured).
        depth: (D,) or scalar Z (mm); float64 recommended.
        lateral_mm: x of the points (default on the axis).

    Raises:
        AnalysisError: if a point is not seen by both halves.

    Example:
        >>> s = exact_sensitivities(thesis_setup1(), [1000.0])
        >>> round(float(s.D[0]), 1), round(float(s.T_o[0]), 3)
        (2148.0, 5.872)
    """
    z = _depths(depth)
    p0 = as_parameters(rig, z)
    pair = _exact_pixels(p0, z, as_tensor(lateral_mm, z, "lateral_mm"))
    names = ("alpha", "n", "f", "T", "T_o")
    with torch.enable_grad():
        leaves = {k: getattr(p0, k).detach().clone().requires_grad_(True) for k in names}
        p = p0._replace(**leaves)
        uv_r = pair.uv_right.detach().clone().requires_grad_(True)
        zz = depth_exact(p, pair.uv_left.detach(), uv_r).depth
        (g_uv,) = torch.autograd.grad(zz.sum(), uv_r, retain_graph=True)
        rows = []
        for i in range(zz.shape[0]):
            rows.append(torch.stack(torch.autograd.grad(zz[i], [leaves[k] for k in names], retain_graph=True)))
    jac = torch.stack(rows).detach()  # (D, 5)
    dd = g_uv[..., 0].detach() / p0.pixel_size.detach()
    return Sensitivities(D=dd, T_o=jac[:, 4], alpha=jac[:, 0], f=jac[:, 2], n=jac[:, 1], T=jac[:, 3])


def error_budget(
    rig: BiPrismRig | RigParameters,
    depth: torch.Tensor | float,
    uncertainties: Uncertainties | None = None,
    model: Model = "closed_form",
    lateral_mm: float = 0.0,
) -> ErrorBudget:
    """Absolute and relative depth error from parameter uncertainties (eq. 6.17-6.18, fig. 6.3-6.6).

    Args:
        rig: rig or tensors.
        depth: (D,) or scalar Z (mm).
        uncertainties: default :class:`Uncertainties` (fig. 6.5: df 0.1 mm, dalpha 0.001 rad, dT_o 1 mm,
            dn 0.01, dD 1 px).
        model: 'closed_form' (thesis, eq. 6.22-6.34 with dZ/dn corrected) or 'exact' (autograd).
        lateral_mm: x of the points for the exact model.

    Example:
        >>> b = error_budget(thesis_setup1(), [500.0, 1000.0])
        >>> [round(v, 2) for v in b.contributions.D.tolist()]   # mm, 1 px disparity error
        [2.53, 10.17]
    """
    check_option(model, ("closed_form", "exact"), "model")
    u = uncertainties if uncertainties is not None else Uncertainties()
    if not isinstance(u, Uncertainties):
        raise AnalysisError(f"uncertainties must be an Uncertainties, got {type(u).__name__}")
    z = _depths(depth)
    sens = closed_form_sensitivities(rig, z) if model == "closed_form" else exact_sensitivities(rig, z, lateral_mm)
    pixel = float(as_parameters(rig, z).pixel_size)
    steps = Sensitivities(D=u.disparity_px * pixel, T_o=u.apex_distance_mm, alpha=u.alpha_rad,
                          f=u.focal_length_mm, n=u.refractive_index, T=u.thickness_mm)
    contrib = Sensitivities(*[s.detach().abs() * step for s, step in zip(sens, steps, strict=True)])
    stack = torch.stack(list(contrib))
    total = stack.sum(0)
    return ErrorBudget(z, Sensitivities(*[s.detach() for s in sens]), contrib, total,
                       stack.square().sum(0).sqrt(), total / z)


def error_curves(
    rig: BiPrismRig | RigParameters, depth: torch.Tensor | float, disparity_px: float = 1.0, lateral_mm: float = 0.0
) -> ErrorCurves:
    """Absolute depth error of a disparity error of ``disparity_px`` (fig. 6.3): closed form (eq. 6.22 =
    6.36) and exact model.

    Example:
        >>> c = error_curves(thesis_setup1(), [1000.0])
        >>> round(float(c.closed_form[0]), 2), round(float(c.exact[0]), 2)
        (10.17, 9.99)
    """
    if not math.isfinite(disparity_px) or disparity_px <= 0:
        raise AnalysisError(f"disparity_px must be > 0, got {disparity_px!r}")
    z = _depths(depth)
    step = disparity_px * float(as_parameters(rig, z).pixel_size)
    closed = closed_form_sensitivities(rig, z).D.detach().abs() * step
    exact = exact_dz_dd(rig, z, lateral_mm).abs() * step
    return ErrorCurves(z, closed, exact)


# ----------------------------------------------------------------------------------- validity of 6.15
def small_angle_check(
    rig: BiPrismRig,
    depth: torch.Tensor | float,
    lateral_fractions: tuple[float, ...] = (-0.9, -0.45, 0.0, 0.45, 0.9),
    threshold: float = 0.01,
    y_mm: float = 0.0,
) -> SmallAngleCheck:
    """Where does eq. 6.15 lose accuracy? Relative depth errors of eq. 6.15 and of the planar general form
    (eq. 6.9) for exact points spread over the common FOV.

    At each depth the points are (c + k w / 2, y_mm, Z) for k in ``lateral_fractions``, with c and w the
    centre and width of the exact common FOV (principal row); each is projected exactly into both halves
    and its disparity fed to the closed forms.

    Args:
        rig: the rig.
        depth: (D,) depths (mm), beyond the back plane.
        lateral_fractions: positions across the common FOV, in (-1, 1).
        threshold: relative error reported by ``first_depth_over`` (default 1 %).
        y_mm: height of the points (the closed forms ignore it; nonzero shows the off-row error).

    Example:
        >>> chk = small_angle_check(thesis_setup1(), [300.0, 1000.0], lateral_fractions=(0.0,))
        >>> [round(e, 4) for e in chk.error_small_angle[:, 0].tolist()], chk.first_depth_over
        ([0.0012, 0.0304], 1000.0)
    """
    if not isinstance(rig, BiPrismRig):
        raise AnalysisError(f"rig must be a BiPrismRig, got {type(rig).__name__}")
    if not 0 < threshold < 1:
        raise AnalysisError(f"threshold must be in (0, 1), got {threshold}")
    if not lateral_fractions or any(not -1 < k < 1 for k in lateral_fractions):
        raise AnalysisError(f"lateral_fractions must be non-empty values in (-1, 1), got {lateral_fractions}")
    ext = exact_fov_extent(rig, depth)
    z = ext.depth
    if not bool(ext.overlap.all()):
        raise AnalysisError(f"no common FOV at depth {float(z[~ext.overlap][0]):g} mm")
    frac = torch.tensor(lateral_fractions, dtype=z.dtype)
    centre, half = ext.common.mean(-1, keepdim=True), ext.width[:, None] / 2
    x = centre + frac * half
    zz = z[:, None].expand_as(x)
    points = torch.stack([x, torch.full_like(x, y_mm), zz], -1)
    pair = project_pair(rig, points)
    z615 = depth_small_angle(rig, pair.disparity)
    xl = (pair.uv_left[..., 0] - rig.cx) * rig.pixel_size_mm
    xr = (pair.uv_right[..., 0] - rig.cx) * rig.pixel_size_mm
    zpl = depth_planar(rig, xl, xr)
    e615, epl = (z615 - zz) / zz, (zpl - zz) / zz
    over = ((e615.abs() > threshold) & pair.valid).any(-1)
    first = float(z[over].min()) if bool(over.any()) else math.nan
    return SmallAngleCheck(z, x, e615, epl, pair.valid, float(threshold), first)
