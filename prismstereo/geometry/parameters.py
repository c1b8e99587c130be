"""A rig's parameters as tensors (:class:`RigParameters`), the input of every differentiable optics function.

:class:`~prismstereo.geometry.rig.BiPrismRig` holds a rig's numbers as a frozen, validated, JSON-ready record;
:meth:`~prismstereo.geometry.rig.BiPrismRig.parameters` turns them into this tensor form (angles in radians), whose
fields may require grad, so every rig parameter can be optimised (self-calibration, the cost volume's rig
gradients). Conventions are those of :mod:`prismstereo.geometry.rig` and :mod:`prismstereo.conventions`.

:func:`split_column` is where the two half-images meet on the sensor (the image of the prism's apex line): both
forms of a rig derive their reference width from it.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import torch

__all__ = ["RigParameters", "split_column"]


class RigParameters(NamedTuple):
    """A rig's parameters as tensors: the input of every differentiable optics function.

    All tensor fields are 0-d tensors of one dtype and device (``tilt`` has shape (3,)); any of them may
    require grad. ``width``/``height`` are plain ints (the sensor size is discrete).

    Attributes:
        alpha: prism corner angle (rad).
        n: refractive index of the glass.
        f: focal length (mm).
        T: prism thickness, apex to back plane (mm).
        T_o: optical centre to apex distance (mm).
        pixel_size: square pixel pitch (mm).
        cx: principal point column (px).
        cy: principal point row (px).
        d: x offset of the apex line (mm).
        tilt: (3,) prism rotation about the apex point (rad): about x, y, z, applied as R_z R_y R_x.
        distortion: (5,) lens distortion ``(k1, k2, p1, p2, k3)`` (OpenCV's model on the real camera's
            normalised coordinates, :mod:`prismstereo.geometry.distortion`), or None for a distortion-free lens
            (the pinhole formulas, no undistortion iterations).
        width: image width (px).
        height: image height (px).
    """

    alpha: torch.Tensor
    n: torch.Tensor
    f: torch.Tensor
    T: torch.Tensor
    T_o: torch.Tensor
    pixel_size: torch.Tensor
    cx: torch.Tensor
    cy: torch.Tensor
    d: torch.Tensor
    tilt: torch.Tensor
    distortion: torch.Tensor | None
    width: int
    height: int

    def detach(self) -> RigParameters:
        """The same parameters with every tensor detached (no autograd, reverse or forward mode: ``no_grad`` alone
        does not stop forward-mode tangents).

        Example:
            >>> p = thesis_setup1().parameters(); p = p._replace(f=p.f.clone().requires_grad_())
            >>> p.f.requires_grad, p.detach().f.requires_grad
            (True, False)
        """
        return self._replace(**{k: v.detach() for k, v in self._asdict().items() if isinstance(v, torch.Tensor)})

    @property
    def reference_width(self) -> int:
        """W_ref, the columns left of the apex column (see
        :attr:`~prismstereo.geometry.rig.BiPrismRig.reference_width`); not differentiable.

        Example:
            >>> thesis_setup1().parameters().reference_width
            512
        """
        def f(x: torch.Tensor) -> Any:
            return x.detach().tolist()

        k = None if self.distortion is None else f(self.distortion)
        column = split_column(float(f(self.cx)), float(f(self.cy)), float(f(self.f / self.pixel_size)),
                              float(f(self.d)), float(f(self.T_o)), f(self.tilt), k, self.height)
        return min(self.width, max(0, math.ceil(column)))

    def to(self, like: torch.Tensor) -> RigParameters:
        """Return the parameters on ``like``'s device and dtype (autograd is preserved).

        Example:
            >>> p = thesis_setup1().parameters().to(torch.zeros(1, dtype=torch.float64))
            >>> p.alpha.dtype
            torch.float64
        """
        fields = {
            k: (v.to(device=like.device, dtype=like.dtype) if isinstance(v, torch.Tensor) else v)
            for k, v in self._asdict().items()
        }
        return RigParameters(**fields)


def split_column(cx: float, cy: float, focal_px: float, d: float, T_o: float, tilt_rad: Any,
                 distortion: Any, height: int) -> float:
    """The rightmost image column of the prism's apex line over the sensor rows [-0.5, H - 0.5] (px).

    The apex line A + t a, A = (d, 0, T_o), a = R (0, 1, 0) with R the prism's tilt, projected through the
    pinhole and the lens distortion (if any). Untilted about x and z and distortion-free it is the vertical
    line u = cx + f_px d / T_o (returned exactly); otherwise the line is sampled densely (4097 points over
    twice the sensor's height) and, distortion-free, its exact ends on the edge rows are added.

    Args:
        cx, cy: principal point (px).
        focal_px: focal length (px).
        d: x offset of the apex line (mm).
        T_o: optical centre to apex distance (mm).
        tilt_rad: the prism's three tilt angles (rad), about x, y, z.
        distortion: the five lens distortion coefficients, or None for a distortion-free lens.
        height: sensor rows H.

    Returns:
        The column (px), not rounded.

    Example:
        >>> split_column(511.5, 383.5, 5376.3, 0.0, 170.0, [0.0, 0.0, 0.0], None, 768)
        511.5
    """
    tx, ty, tz = (float(a) for a in tilt_rad)
    if tx == 0.0 and tz == 0.0 and distortion is None:
        return cx + focal_px * d / T_o
    # a = R_z R_y R_x e_y
    ax, ay, az = 0.0, math.cos(tx), math.sin(tx)
    ax, az = ax * math.cos(ty) + az * math.sin(ty), -ax * math.sin(ty) + az * math.cos(ty)
    ax, ay = ax * math.cos(tz) - ay * math.sin(tz), ax * math.sin(tz) + ay * math.cos(tz)
    reach = height / focal_px * T_o  # the sensor's height seen at the apex depth, mm
    t = torch.linspace(-reach, reach, 4097, dtype=torch.float64)
    x, y, z = d + t * ax, t * ay, T_o + t * az
    xy = torch.stack([x / z, y / z], dim=-1)
    if distortion is not None:
        from prismstereo.geometry.distortion import distort

        xy = distort(xy, torch.tensor(list(distortion), dtype=torch.float64))
    u, v = cx + focal_px * xy[:, 0], cy + focal_px * xy[:, 1]
    on = (v >= -0.5) & (v <= height - 0.5)
    ends = []
    if distortion is None:  # the line is straight in the image: its exact ends on the edge rows
        for edge in (-0.5, height - 0.5):
            den = focal_px * ay - (edge - cy) * az
            if abs(den) > 1e-12:
                te = (edge - cy) * T_o / den
                ends.append(cx + focal_px * (d + te * ax) / (T_o + te * az))
    best = float(u[on].max()) if bool(on.any()) else cx + focal_px * d / T_o
    return max([best, *ends])

