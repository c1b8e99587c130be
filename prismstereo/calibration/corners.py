"""Sub-pixel refinement of board corners by point symmetry.

A checkerboard or ChArUco corner is point-symmetric: seen through any locally affine mapping (perspective, the
prism's anisotropic magnification) and any point-symmetric blur (defocus, pixel integration), the image around
it satisfies I(c + d) = I(c - d). Its position c is therefore the minimiser of

    E(c, g) = sum_d w(d) (J(c + d) - J(c - d) - 2 g.d)^2,

with J the image smoothed by a small Gaussian, d over a disk of radius r and g a local intensity gradient
(vignetting, the prism faces' different Fresnel transmission) that would otherwise pull the corner towards the
brighter side. Gauss-Newton on (c, g), a fixed number of steps, all corners at once.

OpenCV's detectors find the corners and their ids; this refinement replaces their positions (several times closer
to the exact projections on rendered boards: ``benchmarks/corners.py``). The disk must stay inside the corner's
symmetric neighbourhood: a ChArUco marker's inner bits start a quarter of a square from each corner, so the
default radius is 0.15 of the local corner spacing.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
import torch.nn.functional as F

from prismstereo.errors import CalibrationError

__all__ = ["CornerRefinement", "refine_corners", "corner_spacing"]


class CornerRefinement(NamedTuple):
    """Refined corners.

    Attributes:
        uv: (N, 2) refined positions (pixels, centres at integers), the input's dtype.
        converged: (N,) bool, False where the refinement moved more than the disk radius, hit the image border,
            or found no corner structure (a singular normal matrix); those rows keep their input position.
    """

    uv: torch.Tensor
    converged: torch.Tensor


def corner_spacing(uv: torch.Tensor) -> torch.Tensor:
    """Distance from each corner to its nearest neighbour among ``uv``: the local scale of the board.

    Args:
        uv: (N, 2) corners of one half-image, N >= 2.

    Returns:
        (N,) distances in pixels.

    Example:
        >>> corner_spacing(torch.tensor([[0.0, 0.0], [3.0, 4.0], [3.0, 21.0]]))
        tensor([ 5.,  5., 17.])
    """
    if uv.ndim != 2 or uv.shape[-1] != 2 or uv.shape[0] < 2:
        raise CalibrationError(f"uv must be (N, 2) with N >= 2, got {tuple(uv.shape)}")
    d = torch.cdist(uv, uv)
    d.fill_diagonal_(float("inf"))
    return d.min(dim=1).values


def _sample(image: torch.Tensor, xy: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of (C, H, W) ``image`` at (N, K, 2) pixel positions -> (C, N, K), border replicated."""
    h, w = image.shape[-2:]
    norm = torch.stack([2.0 * xy[..., 0] / (w - 1) - 1.0, 2.0 * xy[..., 1] / (h - 1) - 1.0], dim=-1)
    return F.grid_sample(image[None], norm[None].to(image.dtype), mode="bilinear", padding_mode="border",
                         align_corners=True)[0]


def refine_corners(
    image: torch.Tensor,
    uv: torch.Tensor,
    *,
    radius_px: float | torch.Tensor | None = None,
    sigma_px: float = 1.0,
    iterations: int = 10,
    step_px: float = 0.5,
) -> CornerRefinement:
    """Refine corner positions to the centre of point symmetry of the image around them.

    Args:
        image: (H, W) or (1, H, W) grey image, float in [0, 1] (uint8 tensors are scaled by 1/255).
        uv: (N, 2) starting positions (pixels, centres at integers), e.g. OpenCV's corners, within ~r/2 of
            the true ones.
        radius_px: radius r of the symmetric disk, a float or an (N,) tensor; default 0.15 x each corner's
            :func:`corner_spacing`, clamped to [2, 10] px.
        sigma_px: Gaussian smoothing of the image before sampling (px, >= 0).
        iterations: Gauss-Newton steps (fixed count, each step clamped to 0.5 px).
        step_px: spacing of the samples on the disk (px, > 0).

    Returns:
        CornerRefinement(uv (N, 2), converged (N,)).

    Raises:
        CalibrationError: bad shapes or options.

    Example:
        >>> yy, xx = torch.meshgrid(torch.arange(40.0), torch.arange(40.0), indexing="ij")
        >>> board = ((xx > 20.5) ^ (yy > 17.5)).double()  # the corner between pixels 20 | 21 and 17 | 18
        >>> out = refine_corners(board, torch.tensor([[20.1, 18.2]]), radius_px=4.0)
        >>> out.uv.round(decimals=3), bool(out.converged)
        (tensor([[20.5000, 17.5000]]), True)
    """
    image = _check(image, uv, sigma_px, step_px, iterations)
    n = uv.shape[0]
    if n == 0:
        return CornerRefinement(uv.clone(), torch.zeros(0, dtype=torch.bool, device=uv.device))
    dtype = torch.float64
    img = image.to(device=uv.device, dtype=dtype) / (255.0 if image.dtype == torch.uint8 else 1.0)
    radius = _radius(uv, radius_px, dtype)
    img, stack = _smoothed(img, sigma_px)
    d, weight = _disk(radius, step_px, dtype, uv.device)
    c, a = _gauss_newton(stack, uv.to(dtype).clone(), d, weight, iterations)
    moved = (c - uv.to(dtype)).norm(dim=-1)
    # A corner has strong symmetric-difference gradients in two directions: an edge or a flat patch has not.
    eig = torch.linalg.eigvalsh(a[:, :2, :2])
    structure = (eig[:, 1] > 1e-4 * weight.sum(-1)) & (eig[:, 0] > 0.05 * eig[:, 1])
    h, w = img.shape
    inside_image = (c[:, 0] >= radius) & (c[:, 0] <= w - 1 - radius) & (c[:, 1] >= radius) & (c[:, 1] <= h - 1 - radius)
    converged = (moved <= radius) & structure & inside_image & torch.isfinite(c).all(-1)
    out = torch.where(converged[:, None], c, uv.to(dtype))
    return CornerRefinement(out.to(uv.dtype), converged)


def _check(image: torch.Tensor, uv: torch.Tensor, sigma_px: float, step_px: float, iterations: int) -> torch.Tensor:
    """The (H, W) image, after checking the shapes and options of :func:`refine_corners`."""
    if image.ndim == 3 and image.shape[0] == 1:
        image = image[0]
    if image.ndim != 2:
        raise CalibrationError(f"image must be (H, W) or (1, H, W), got {tuple(image.shape)}")
    if uv.ndim != 2 or uv.shape[-1] != 2:
        raise CalibrationError(f"uv must be (N, 2), got {tuple(uv.shape)}")
    if not (sigma_px >= 0 and step_px > 0 and iterations >= 1):
        raise CalibrationError(f"need sigma_px >= 0, step_px > 0, iterations >= 1; got {sigma_px}, {step_px}, "
                               f"{iterations}")
    return image


def _radius(uv: torch.Tensor, radius_px: float | torch.Tensor | None, dtype: torch.dtype) -> torch.Tensor:
    """(N,) disk radii: ``radius_px``, or 0.15 x each corner's spacing clamped to [2, 10] px (4 px for one corner)."""
    n = uv.shape[0]
    if radius_px is None:
        radius = (0.15 * corner_spacing(uv.to(dtype))).clamp(2.0, 10.0) if n >= 2 else uv.new_full((1,), 4.0)
    else:
        radius = torch.as_tensor(radius_px, dtype=dtype, device=uv.device).expand(n)
    if not bool((radius > 0).all()):
        raise CalibrationError("radius_px must be > 0")
    return radius.to(dtype)


def _smoothed(img: torch.Tensor, sigma_px: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The (H, W) image J smoothed by a Gaussian of ``sigma_px`` (none at 0), and (3, H, W) J with its d/du, d/dv."""
    if sigma_px > 0:
        k = 2 * math.ceil(3 * sigma_px) + 1
        # kornia imported where used: a cached graph's depth run never loads it
        from kornia.filters import gaussian_blur2d

        img = gaussian_blur2d(img[None, None], (k, k), (sigma_px, sigma_px), border_type="replicate")[0, 0]
    grad = torch.stack([torch.gradient(img, dim=1)[0], torch.gradient(img, dim=0)[0]])  # (2, H, W): d/du, d/dv
    return img, torch.cat([img[None], grad])  # (3, H, W)


def _disk(radius: torch.Tensor, step_px: float, dtype: torch.dtype,
          device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """Half a disk of offsets d (K, 2) (d and -d give the same residual) on a grid of ``step_px``, and their (N, K)
    Gaussian weights within each corner's radius (0 outside)."""
    m = math.ceil(float(radius.max()) / step_px)
    g = torch.arange(-m, m + 1, dtype=dtype, device=device) * step_px
    dy, dx = torch.meshgrid(g, g, indexing="ij")
    half = (dy > 0) | ((dy == 0) & (dx > 0))
    d = torch.stack([dx[half], dy[half]], dim=-1)  # (K, 2)
    dist2 = d.pow(2).sum(-1)
    inside = dist2[None] <= radius[:, None] ** 2  # (N, K)
    weight = torch.exp(-dist2[None] / (2 * (radius[:, None] / 2) ** 2)) * inside
    return d, weight


def _gauss_newton(stack: torch.Tensor, c: torch.Tensor, d: torch.Tensor, weight: torch.Tensor,
                  iterations: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``iterations`` Gauss-Newton steps on (c, g) from the (N, 2) corners ``c`` (each step clamped to 0.5 px).
    Returns the corners and the last (N, 4, 4) normal matrix."""
    n = c.shape[0]
    for _ in range(iterations):
        plus = _sample(stack, c[:, None] + d[None])
        minus = _sample(stack, c[:, None] - d[None])
        res = plus[0] - minus[0]  # (N, K)
        jc = (plus[1:] - minus[1:]).permute(1, 2, 0)  # (N, K, 2): d res / d c
        jg = -2.0 * d[None].expand(n, -1, -1)  # (N, K, 2): d res / d g
        jac = torch.cat([jc, jg], dim=-1)  # (N, K, 4)
        a = torch.einsum("nk,nki,nkj->nij", weight, jac, jac)
        b = torch.einsum("nk,nki,nk->ni", weight, jac, res)
        a = a + 1e-12 * torch.eye(4, dtype=c.dtype, device=c.device)
        step = -torch.linalg.solve(a, b)[:, :2]
        c = c + step.clamp(-0.5, 0.5)
    return c, a
