"""Shared helpers of the analysis package: its error type, tensor coercion and a scalar root finder."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import torch

from prismstereo.errors import PrismStereoError
from prismstereo.geometry.parameters import RigParameters
from prismstereo.geometry.rig import BiPrismRig

__all__ = ["AnalysisError", "as_tensor", "check_positive", "check_rig", "depths_beyond", "brent", "check_untilted"]


class AnalysisError(PrismStereoError, ValueError):
    """Invalid input to an analysis function (FOV, depth error, design), or an unreachable design target."""


def as_tensor(value: Any, like: torch.Tensor | None = None, name: str = "value") -> torch.Tensor:
    """``value`` as a floating tensor: tensors keep their dtype/device, numbers become float64 (or ``like``'s).

    Raises:
        AnalysisError: if ``value`` is not a number, a sequence of numbers or a floating/integer tensor.
    """
    if isinstance(value, torch.Tensor):
        if not (torch.is_floating_point(value) or value.dtype in (torch.int32, torch.int64)):
            raise AnalysisError(f"{name} must be a real tensor, got dtype {value.dtype}")
        return value if torch.is_floating_point(value) else value.to(torch.float64)
    dtype = like.dtype if like is not None else torch.float64
    device = like.device if like is not None else None
    try:
        out = torch.as_tensor(value, dtype=dtype, device=device)
    except (TypeError, ValueError, RuntimeError) as exc:
        raise AnalysisError(f"{name} must be a number or a tensor, got {value!r}") from exc
    return out


def check_positive(value: torch.Tensor, name: str, *, strict: bool = True) -> None:
    """Raise :class:`AnalysisError` unless every element is finite and > 0 (>= 0 when not ``strict``)."""
    v = value.detach()
    bad = ~torch.isfinite(v) | ((v <= 0) if strict else (v < 0))
    if bool(bad.any()):
        bound = "> 0" if strict else ">= 0"
        raise AnalysisError(f"{name} must be finite and {bound}, got {v[bad].flatten()[0].item()!r}")


def check_rig(rig: object) -> None:
    """Raise :class:`AnalysisError` unless ``rig`` is a :class:`BiPrismRig` (the ray-traced analyses take one)."""
    if not isinstance(rig, BiPrismRig):
        raise AnalysisError(f"rig must be a BiPrismRig, got {type(rig).__name__}")


def depths_beyond(depth: torch.Tensor | float, back_plane_z: float) -> torch.Tensor:
    """``depth`` as a (D,) tensor; :class:`AnalysisError` unless every depth is finite and beyond the prism's
    back plane at ``back_plane_z`` (mm)."""
    depth = as_tensor(depth, name="depth").reshape(-1)
    if depth.numel() == 0 or bool((~torch.isfinite(depth) | (depth <= back_plane_z)).any()):
        raise AnalysisError(f"depths must be finite and beyond the prism's back plane (> {back_plane_z:.3f} mm)")
    return depth


def check_untilted(rig: BiPrismRig | RigParameters, what: str) -> None:
    """The thesis' closed forms assume an untilted prism; refuse a tilted one."""
    tilt = rig.prism_tilt_deg if isinstance(rig, BiPrismRig) else tuple(float(t) for t in rig.tilt.detach())
    if any(abs(t) > 0 for t in tilt):
        raise AnalysisError(
            f"{what} assumes an untilted prism (thesis ch. 5-6); got prism tilt {tilt}. "
            "Use the exact ray-traced functions for a tilted prism."
        )


def brent(fun: Callable[[float], float], lo: float, hi: float, *, xtol: float = 1e-12, iterations: int = 200) -> float:
    """Root of ``fun`` in [lo, hi] (a sign change is required) by Brent's method (bisection safeguarded).

    Raises:
        AnalysisError: if ``fun(lo)`` and ``fun(hi)`` have the same sign.
    """
    a, b = float(lo), float(hi)
    fa, fb = fun(a), fun(b)
    if fa == 0.0:
        return a
    if fb == 0.0:
        return b
    if not (math.isfinite(fa) and math.isfinite(fb)) or (fa > 0) == (fb > 0):
        raise AnalysisError(f"no sign change in [{a:g}, {b:g}] (f = {fa:g}, {fb:g})")
    c, fc = a, fa
    d = e = b - a
    for _ in range(iterations):
        if (fb > 0) == (fc > 0):
            c, fc = a, fa
            d = e = b - a
        if abs(fc) < abs(fb):
            a, b, c = b, c, b
            fa, fb, fc = fb, fc, fb
        tol = 2.0 * 2.2e-16 * abs(b) + 0.5 * xtol
        m = 0.5 * (c - b)
        if abs(m) <= tol or fb == 0.0:
            return b
        if abs(e) >= tol and abs(fa) > abs(fb):
            s = fb / fa
            if a == c:
                p, q = 2.0 * m * s, 1.0 - s
            else:
                q, r = fa / fc, fb / fc
                p = s * (2.0 * m * q * (q - r) - (b - a) * (r - 1.0))
                q = (q - 1.0) * (r - 1.0) * (s - 1.0)
            if p > 0:
                q = -q
            p = abs(p)
            if 2.0 * p < min(3.0 * m * q - abs(tol * q), abs(e * q)):
                e, d = d, p / q
            else:
                d = e = m
        else:
            d = e = m
        a, fa = b, fb
        b = b + (d if abs(d) > tol else math.copysign(tol, m))
        fb = fun(b)
    return b
