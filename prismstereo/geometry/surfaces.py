"""The bi-prism's surfaces and Snell's law at them: the planes the ray tracer crosses.

Geometry in the prism's own frame (origin at the apex point A = (d, 0, T_o), axes those of the camera rotated by
the rig's tilt R = R_z R_y R_x, :func:`euler_rotation`): the left face is the plane z' = -x' tan(alpha) with unit
normal n_L = (sin a, 0, cos a), the right face z' = x' tan(alpha) with n_R = (-sin a, 0, cos a), and the back plane
z' = T with n_B = (0, 0, 1). The glass is the convex set {n_L.(p-A) >= 0, n_R.(p-A) >= 0, n_B.(p-B) <= 0}, B the
back plane's point on the prism's axis. :func:`refract` bends a ray at one of these planes (vector Snell, thesis
eq. 3.5-3.10), flagging total internal reflection instead of returning NaN.

These are the pieces :mod:`prismstereo.geometry.optics` assembles into the traced rays; they live apart so the
tracer reads as the thesis' ray construction. Conventions: :mod:`prismstereo.conventions`.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from prismstereo.errors import check_shape
from prismstereo.geometry.parameters import RigParameters
from prismstereo.runtime import tracing

__all__ = ["Refraction", "refract", "euler_rotation"]


class Refraction(NamedTuple):
    """Result of :func:`refract`.

    Attributes:
        directions: (*, 3) unit refracted directions (finite even where invalid).
        valid: (*,) False where the ray is totally internally reflected.
    """

    directions: torch.Tensor
    valid: torch.Tensor


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Dot products over the last axis (3-vectors).

    torch's sum over an axis of 3 is slow on large batches (several times the products' time); the products' three
    columns added in order give the same float as the sum, bit for bit (its order, and + 0.0 turns -0.0 into 0.0
    as the sum's zero start does). That form runs on large batches in eager code without autograd through the
    inputs; with autograd or in an export the sum stays (its gradients and the exported graph are unchanged)."""
    if (a.shape[-1] == b.shape[-1] == 3 and max(a.numel(), b.numel()) >= _LARGE_DOT and not tracing()
            and not (torch.is_grad_enabled() and (a.requires_grad or b.requires_grad))):
        p = a * b
        return p[..., 0] + p[..., 1] + p[..., 2] + 0.0
    return (a * b).sum(-1)


_LARGE_DOT = 3 * 4096


def refract(incident: torch.Tensor, normal: torch.Tensor, eta: torch.Tensor | float) -> Refraction:
    """Vector form of Snell's law (thesis eq. 3.1 and 3.5-3.10 without the per-ray frames).

    t = eta i + (eta cos(theta_i) - sqrt(k)) m, with cos(theta_i) = -m.i and k = 1 - eta^2 (1 - cos^2).

    Args:
        incident: (*, 3) unit direction of the incoming ray.
        normal: (*, 3) unit surface normal facing the incoming ray (m . i < 0); broadcastable.
        eta: ratio n_from / n_to of refractive indices (tensor or float, broadcastable to (*,)).

    Returns:
        Refraction(directions (*, 3), valid (*,)): valid is False on total internal reflection (k <= 0);
        there the direction is finite but meaningless.

    Example:
        >>> i = torch.tensor([0.6, 0.0, 0.8]); m = torch.tensor([0.0, 0.0, -1.0])
        >>> refract(i, m, 1.0 / 1.5).directions.shape
        torch.Size([3])
    """
    cos_i = -_dot(normal, incident)
    k = 1.0 - eta * eta * (1.0 - cos_i * cos_i)
    valid = k > 0
    root = torch.sqrt(k.clamp_min(torch.finfo(incident.dtype).eps))
    out = eta * incident + ((eta * cos_i - root).unsqueeze(-1)) * normal
    return Refraction(out, valid)


def euler_rotation(angles: torch.Tensor) -> torch.Tensor:
    """Rotation matrix R = R_z R_y R_x from angles (rad) about x, y, z (the rig's ``prism_tilt_deg`` order).

    Args:
        angles: (3,) tensor.

    Returns:
        (3, 3) rotation, differentiable.

    Example:
        >>> euler_rotation(torch.tensor([0.0, 0.0, 0.0]))
        tensor([[1., 0., 0.],
                [0., 1., 0.],
                [0., 0., 1.]])
    """
    check_shape(angles, [3], "angles")
    return _rotation(angles)


def _rotation(tilt: torch.Tensor) -> torch.Tensor:
    """R = R_z R_y R_x from the (3,) tilt angles (rad)."""
    c, s = torch.cos(tilt), torch.sin(tilt)
    one, zero = torch.ones_like(tilt[0]), torch.zeros_like(tilt[0])
    rx = torch.stack([one, zero, zero, zero, c[0], -s[0], zero, s[0], c[0]]).view(3, 3)
    ry = torch.stack([c[1], zero, s[1], zero, one, zero, -s[1], zero, c[1]]).view(3, 3)
    rz = torch.stack([c[2], -s[2], zero, s[2], c[2], zero, zero, zero, one]).view(3, 3)
    return rz @ ry @ rx


class _Planes(NamedTuple):
    """The prism's planes in the camera frame: the apex (on both faces), a point of the back plane, the unit normals."""

    apex: torch.Tensor  # (3,)
    back: torch.Tensor  # (3,) a point of the back plane
    n_left: torch.Tensor  # (3,)
    n_right: torch.Tensor  # (3,)
    n_back: torch.Tensor  # (3,)


def _planes(p: RigParameters) -> _Planes:
    """The prism's faces and back plane for the rig's tensors (tilted by R about the apex point)."""
    sa, ca = torch.sin(p.alpha), torch.cos(p.alpha)
    zero, one = torch.zeros_like(sa), torch.ones_like(sa)
    rot = _rotation(p.tilt)
    apex = torch.stack([p.d, zero, p.T_o])
    return _Planes(
        apex=apex,
        back=apex + rot @ torch.stack([zero, zero, p.T]),
        n_left=rot @ torch.stack([sa, zero, ca]),
        n_right=rot @ torch.stack([-sa, zero, ca]),
        n_back=rot @ torch.stack([zero, zero, one]),
    )
