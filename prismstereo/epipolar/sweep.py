"""The exact plane sweep as a Chebyshev tensor: m(u, v, s) for every reference pixel and depth.

The right-half correspondence of reference pixel (u, v) at depth Z is the exact ray-traced projection
(eq. 3.1-3.10 forward, :func:`~prismstereo.geometry.projection.solve_projection` backward) of the point on the
pixel's ray at that depth; as Z varies it traces the exact epipolar curve (thesis ch. 4, eq. 4.1-4.10
approximate it by a straight line). The map is analytic in all three variables, so a tensor-product
Chebyshev interpolant

    m(u, v, s) = sum_{a, b, c} A[a, b, c] T_a(s) T_b(y(v)) T_c(x(u)),

with s in [-1, 1] linear in inverse depth (s = -1 at z_min, +1 at z_max; uniform s is the usual
uniform-disparity hypothesis spacing), x(u) = 2 (u + 0.5) / W_ref - 1 and y(v) = 2 (v + 0.5) / H - 1,
reproduces it to machine precision from a few thousand exact projections. Measured over 228-1374 mm
(37 x 29 pixels x 41 depths, none at the nodes): ``thesis_setup1`` 8 x 8 x 13 nodes 3.7e-11 px max;
``thesis_setup2`` 3.3e-6 px (12 x 12 x 13: 6.2e-7 px). The full exact grid of a 1024 x 768 sensor at 368 depths
(:func:`~prismstereo.epipolar.grids.exact_sampling_grid`) needs ~145 million projections instead. A fit of a
:class:`~prismstereo.geometry.rig.BiPrismRig` is kept, so models built again for the same rig and range (every
level, option set and export of it) copy it instead of fitting again.

The interpolant continues analytically through depths where the real ray does not exist (the point left
the right half's field of view): the projection uses the prism face's infinite plane. Whether a sample is
real is decided where it is used: inside the right half, on a right pixel whose own ray is valid.

Everything is differentiable w.r.t. the rig parameters (pass
:class:`~prismstereo.geometry.parameters.RigParameters` requiring grad) and evaluation is plain arithmetic
(Chebyshev recurrences and sums), so it exports to ONNX.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from typing import NamedTuple

import torch

from prismstereo.errors import OptionError, RigError, check_int, check_shape
from prismstereo.geometry.optics import pixel_directions, points_at_depth, trace_rays
from prismstereo.geometry.parameters import RigParameters
from prismstereo.geometry.projection import solve_projection
from prismstereo.geometry.rig import BiPrismRig, as_parameters
from prismstereo.runtime import tracing

__all__ = [
    "SweepFit",
    "chebyshev_basis",
    "depth_to_sweep",
    "inverse_to_sweep",
    "sweep_to_depth",
    "sweep_to_inverse",
    "fit_sweep",
    "sweep_coefficients",
    "evaluate_sweep",
    "sweep_match",
    "sweep_positions",
    "positions_at",
    "sweep_hypotheses",
    "SWEEP_PROBE_STRIDE",
]

SWEEP_PROBE_STRIDE = 4
""":func:`sweep_hypotheses` probes the sweep's speed on every 4th row and column of the pixel grid."""


class SweepFit(NamedTuple):
    """A fitted exact sweep.

    Attributes:
        coefficients: (N_s, N_v, N_u, 2) Chebyshev coefficients A[a, b, c] of the right-half position
            (u, v) in full-sensor pixels.
        z_range: (2,) (z_min, z_max) in mm; s = -1 at z_min, +1 at z_max.
        reference_width: W_ref, the width of the reference half the x(u) map is defined on.
        height: H.
        max_error_px: largest difference to exact projections at check points between the nodes.
    """

    coefficients: torch.Tensor
    z_range: torch.Tensor
    reference_width: int
    height: int
    max_error_px: float


def chebyshev_basis(x: torch.Tensor, n: int) -> torch.Tensor:
    """T_0(x) .. T_{n-1}(x) by the recurrence T_{k+1} = 2 x T_k - T_{k-1} (ONNX-friendly).

    Args:
        x: (*) values, usually in [-1, 1].
        n: number of polynomials (>= 1).

    Returns:
        (*, n).

    Example:
        >>> chebyshev_basis(torch.tensor([0.5]), 3)
        tensor([[ 1.0000,  0.5000, -0.5000]])
    """
    if n < 1:
        raise OptionError(f"n must be >= 1, got {n}")
    out = [torch.ones_like(x)]
    if n > 1:
        out.append(x)
    for _ in range(2, n):
        out.append(2 * x * out[-1] - out[-2])
    return torch.stack(out, dim=-1)


def _nodes(n: int, like: torch.Tensor) -> torch.Tensor:
    k = torch.arange(n, dtype=like.dtype, device=like.device)
    return torch.cos(torch.pi * (k + 0.5) / n)  # Chebyshev points of the first kind


def depth_to_sweep(depth: torch.Tensor, z_range: torch.Tensor) -> torch.Tensor:
    """Sweep coordinate s = 2 (1/Z - 1/z_min) / (1/z_max - 1/z_min) - 1 (linear in inverse depth).

    Example:
        >>> depth_to_sweep(torch.tensor([300.0, 600.0, 1200.0]), torch.tensor([300.0, 1200.0]))
        tensor([-1.0000,  0.3333,  1.0000])
    """
    return inverse_to_sweep(1.0 / depth, z_range)


def inverse_to_sweep(inverse: torch.Tensor, z_range: torch.Tensor) -> torch.Tensor:
    """Sweep coordinate s = 2 (W - 1/z_min) / (1/z_max - 1/z_min) - 1 of an inverse depth W = 1/Z (1/mm): affine,
    so that a mean or an interpolation of inverse depths is the same of sweep coordinates.

    Example:
        >>> inverse_to_sweep(torch.tensor([1 / 300.0, 1 / 1200.0]), torch.tensor([300.0, 1200.0]))
        tensor([-1.,  1.])
    """
    w0, w1 = 1.0 / z_range[0], 1.0 / z_range[1]
    return 2.0 * (inverse - w0) / (w1 - w0) - 1.0


def sweep_to_inverse(s: torch.Tensor, z_range: torch.Tensor) -> torch.Tensor:
    """Inverse depth 1/Z (1/mm) at sweep coordinate s, the inverse of :func:`inverse_to_sweep`.

    Example:
        >>> (sweep_to_inverse(torch.tensor([-1.0, 1.0]), torch.tensor([300.0, 1200.0])) * 1200.0).round()
        tensor([4., 1.])
    """
    w0, w1 = 1.0 / z_range[0], 1.0 / z_range[1]
    return w0 + (s + 1.0) * 0.5 * (w1 - w0)


def sweep_to_depth(s: torch.Tensor, z_range: torch.Tensor) -> torch.Tensor:
    """Depth Z (mm) at sweep coordinate s, the inverse of :func:`depth_to_sweep`.

    Example:
        >>> sweep_to_depth(torch.tensor([-1.0, 1.0]), torch.tensor([300.0, 1200.0])).round()
        tensor([ 300., 1200.])
    """
    return 1.0 / sweep_to_inverse(s, z_range)


def _exact(p: RigParameters, u: torch.Tensor, v: torch.Tensor, s: torch.Tensor, z_range: torch.Tensor):
    """Exact right positions (N_s, N_v, N_u, 2) and convergence on the face planes' continuation."""
    uv = torch.stack(torch.meshgrid(u, v, indexing="xy"), dim=-1)  # (N_v, N_u, 2)
    rays = trace_rays(p, pixel_directions(p, uv), "left", extended=True)
    out, ok, prev = [], [], None
    for z in sweep_to_depth(s, z_range):
        proj = solve_projection(p, points_at_depth(rays, z), "right", 6, prev, extended=True)
        prev = torch.where(proj.valid.unsqueeze(-1), proj.uv.detach(), torch.full_like(proj.uv, float("nan")))
        out.append(proj.uv)
        ok.append(proj.valid & rays.valid)
    return torch.stack(out), torch.stack(ok)


def _solve(values: torch.Tensor, n_s: int, n_v: int, n_u: int) -> torch.Tensor:
    inv = [torch.linalg.inv(chebyshev_basis(_nodes(n, values), n)) for n in (n_s, n_v, n_u)]
    return torch.einsum("at,bj,ci,tjik->abck", inv[0], inv[1], inv[2], values)


def fit_sweep(
    rig: BiPrismRig | RigParameters,
    z_range_mm: tuple[float, float] | torch.Tensor,
    nodes_uv: int = 8,
    nodes_depth: int = 13,
    tolerance_px: float = 1e-3,
    max_nodes: int = 32,
) -> SweepFit:
    """Fit the exact sweep of the reference half over a depth range.

    Starts from ``nodes_uv`` x ``nodes_uv`` x ``nodes_depth`` Chebyshev nodes and adds 4 nodes per axis
    until the largest error at 7 x 7 x 9 check points between the nodes is below ``tolerance_px``.

    Args:
        rig: the rig; a :class:`BiPrismRig` is fitted in float64, :class:`RigParameters` in their dtype
            (and differentiably).
        z_range_mm: (z_min, z_max), beyond the prism's back plane, increasing.
        nodes_uv: initial nodes along u and v (>= 2).
        nodes_depth: initial nodes along s (>= 2).
        tolerance_px: accepted interpolation error (px).
        max_nodes: upper limit per axis.

    Returns:
        SweepFit.

    Raises:
        RigError: bad range, or the tolerance is not met with ``max_nodes`` (or a node projection fails).

    Example:
        >>> fit = fit_sweep(thesis_setup1().downscaled(8), (300.0, 1200.0))
        >>> fit.coefficients.shape, fit.max_error_px < 1e-3
        (torch.Size([13, 8, 8, 2]), True)
    """
    key = _fit_key(rig, z_range_mm, nodes_uv, nodes_depth, tolerance_px, max_nodes)
    if key is not None:
        with _FITS_LOCK:
            kept = _FITS.get(key)
            if kept is not None:
                _FITS.move_to_end(key)
        if kept is not None:
            return _copy_fit(kept)
    fit = _fit_sweep(rig, z_range_mm, nodes_uv, nodes_depth, tolerance_px, max_nodes)
    if key is not None:
        with _FITS_LOCK:
            _FITS[key] = _copy_fit(fit)
            while len(_FITS) > _FITS_KEPT:
                _FITS.popitem(last=False)
    return fit


# Fits of BiPrismRigs (float64, no autograd), the most recently used first out: each model level fits its rig's
# sweep, and tests, notebooks and applications build several models of one rig and range (levels of a pyramid,
# option sets, exports). A hit returns a copy, bitwise what fitting again gives (the fit is deterministic).
_FITS: OrderedDict[tuple, SweepFit] = OrderedDict()
_FITS_KEPT = 64
_FITS_LOCK = threading.Lock()


def _fit_key(rig, z_range_mm, nodes_uv, nodes_depth, tolerance_px, max_nodes) -> tuple | None:
    """The cache key of a fit of a :class:`BiPrismRig` over a range of plain numbers, else None (not kept).
    Floats enter by their exact hex form (0.0 and -0.0 differ)."""
    numbers = (int, float)
    if not isinstance(rig, BiPrismRig) or not isinstance(z_range_mm, (tuple, list)) or not all(
            isinstance(v, numbers) and not isinstance(v, bool)
            for v in (*z_range_mm, nodes_uv, nodes_depth, tolerance_px, max_nodes)):
        return None
    return (repr(rig), tuple(float(z).hex() for z in z_range_mm), nodes_uv, nodes_depth, float(tolerance_px).hex(),
            max_nodes)


def _copy_fit(fit: SweepFit) -> SweepFit:
    return fit._replace(coefficients=fit.coefficients.clone(), z_range=fit.z_range.clone())


def _fit_sweep(rig, z_range_mm, nodes_uv, nodes_depth, tolerance_px, max_nodes) -> SweepFit:
    p = as_parameters(rig, torch.zeros((), dtype=torch.float64)) if isinstance(rig, BiPrismRig) else rig
    like = p.f
    z = torch.as_tensor(z_range_mm, dtype=like.dtype, device=like.device)
    back = p.T_o + p.T
    if z.shape != (2,) or not bool(back < z[0] < z[1]):
        raise RigError(f"z_range_mm must be (z_min, z_max) beyond the prism's back plane and increasing, got "
                       f"{z.tolist()}")
    if nodes_uv < 2 or nodes_depth < 2:
        raise OptionError(f"need at least 2 nodes per axis, got {nodes_uv}, {nodes_depth}")
    w_ref, h = int(p.reference_width), int(p.height)
    check_s = torch.linspace(-0.97, 0.97, 9, dtype=like.dtype, device=like.device)
    check_u = torch.linspace(-0.45, w_ref - 0.55, 7, dtype=like.dtype, device=like.device)
    check_v = torch.linspace(-0.45, h - 0.55, 7, dtype=like.dtype, device=like.device)
    truth, truth_ok = _exact(p, check_u, check_v, check_s, z)
    n_uv, n_s = nodes_uv, nodes_depth
    while True:
        xu, xv, xs = _nodes(n_uv, like), _nodes(n_uv, like), _nodes(n_s, like)
        values, ok = _exact(p, (xu + 1) * w_ref / 2 - 0.5, (xv + 1) * h / 2 - 0.5, xs, z)
        if not bool(ok.all()):
            raise RigError(f"the exact projection failed at {int((~ok).sum())} sweep nodes over {z.tolist()} mm "
                           "(a ray is totally reflected even on the continued prism faces)")
        coefficients = _solve(values, n_s, n_uv, n_uv)
        fit = SweepFit(coefficients, z, w_ref, h, 0.0)
        est = sweep_positions(fit, torch.stack(torch.meshgrid(check_u, check_v, indexing="xy"), -1),
                              check_s.view(-1, 1, 1))
        err = (est - truth).detach().norm(dim=-1)[truth_ok]
        error = float(err.max()) if err.numel() else 0.0
        if error <= tolerance_px:
            return fit._replace(max_error_px=error)
        if max(n_uv, n_s) + 4 > max_nodes:
            raise RigError(f"sweep fit error {error:.2e} px > {tolerance_px} px with {n_uv}x{n_uv}x{n_s} nodes")
        n_uv, n_s = n_uv + 4, n_s + 4


def _x(u: torch.Tensor, n: int) -> torch.Tensor:
    return 2.0 * (u + 0.5) / n - 1.0


def sweep_coefficients(fit: SweepFit, uv_ref: torch.Tensor) -> torch.Tensor:
    """Per-pixel depth polynomials: C[..., a, :] with m(u, v, s) = sum_a C[..., a, :] T_a(s).

    Args:
        fit: :func:`fit_sweep` result.
        uv_ref: (*, 2) reference pixels (u, v), fractional allowed.

    Returns:
        (*, N_s, 2), dtype of ``uv_ref``.

    Example:
        >>> fit = fit_sweep(thesis_setup1().downscaled(8), (300.0, 1200.0))
        >>> sweep_coefficients(fit, torch.zeros(5, 2, dtype=torch.float64)).shape
        torch.Size([5, 13, 2])
    """
    check_shape(uv_ref, ["*", 2], "uv_ref")
    a = fit.coefficients.to(uv_ref)
    tu = chebyshev_basis(_x(uv_ref[..., 0], fit.reference_width), a.shape[2])  # (*, N_u)
    tv = chebyshev_basis(_x(uv_ref[..., 1], fit.height), a.shape[1])  # (*, N_v)
    pixels = tu[..., 0].numel()
    if pixels > _BLOCK_PIXELS and not tracing() and not (torch.is_grad_enabled() and (a.requires_grad or
                                                                                       uv_ref.requires_grad)):
        # The intermediate (*, N_s, N_v, 2) of a full sensor is hundreds of MB in float64; per block of pixels it
        # stays in the cache. Every pixel's sums are the same, bit for bit; with autograd or in an export the single
        # einsum stays (gradients w.r.t. the coefficients would be summed block by block).
        tu, tv = tu.reshape(pixels, -1), tv.reshape(pixels, -1)
        blocks = [torch.einsum("...b,...abk->...ak", tv[i:i + _BLOCK_PIXELS],
                               torch.einsum("...c,abck->...abk", tu[i:i + _BLOCK_PIXELS], a))
                  for i in range(0, pixels, _BLOCK_PIXELS)]
        return torch.cat(blocks).view(*uv_ref.shape[:-1], a.shape[0], 2)
    inner = torch.einsum("...c,abck->...abk", tu, a)
    return torch.einsum("...b,...abk->...ak", tv, inner)


_BLOCK_PIXELS = 4096


def evaluate_sweep(coefficients: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """Evaluate per-pixel depth polynomials (:func:`sweep_coefficients`) at sweep coordinates.

    Args:
        coefficients: (*, N_s, 2).
        s: sweep coordinates broadcastable to (*).

    Returns:
        (*, 2) right-half positions (full-sensor pixels).

    Example:
        >>> fit = fit_sweep(thesis_setup1().downscaled(8), (300.0, 1200.0))
        >>> c = sweep_coefficients(fit, torch.tensor([[10.0, 20.0]], dtype=torch.float64))
        >>> evaluate_sweep(c, torch.tensor([0.0], dtype=torch.float64)).shape
        torch.Size([1, 2])
    """
    check_shape(coefficients, ["*", "N", 2], "coefficients")
    basis = chebyshev_basis(s.to(coefficients), coefficients.shape[-2])  # (*, N_s)
    return (basis.unsqueeze(-1) * coefficients).sum(dim=-2)


def sweep_positions(fit: SweepFit, uv_ref: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """Right-half positions m(u, v, s) of reference pixels at sweep coordinates (exact to the fit error).

    Args:
        fit: :func:`fit_sweep` result.
        uv_ref: (*, 2) reference pixels.
        s: sweep coordinates broadcastable with ``uv_ref[..., 0]`` (e.g. (D, 1, 1) against (H, W, 2)
            gives a (D, H, W, 2) plane-sweep grid).

    Returns:
        (broadcast shape, 2) positions in full-sensor pixels.

    Example:
        >>> fit = fit_sweep(thesis_setup1().downscaled(8), (300.0, 1200.0))
        >>> uv = torch.zeros(96, 64, 2, dtype=torch.float64)
        >>> sweep_positions(fit, uv, torch.linspace(-1, 1, 4, dtype=torch.float64).view(-1, 1, 1)).shape
        torch.Size([4, 96, 64, 2])
    """
    return evaluate_sweep(sweep_coefficients(fit, uv_ref), s)


def positions_at(coefficients: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """Per-pixel sweep polynomials at coordinates shared by all pixels, by one matrix product.

    Args:
        coefficients: (N, H, W, 2) per-pixel Chebyshev coefficients in s.
        s: (S,) coordinates in [-1, 1].

    Returns:
        (S, H, W, 2) positions, dtype of ``coefficients``.

    Example:
        >>> positions_at(torch.ones(3, 4, 5, 2), torch.tensor([1.0, 0.0])).shape
        torch.Size([2, 4, 5, 2])
    """
    check_shape(coefficients, ["N", "H", "W", 2], "coefficients")
    n = coefficients.shape[0]
    basis = chebyshev_basis(s.to(coefficients), n)  # (S, N)
    return (basis @ coefficients.reshape(n, -1)).view(-1, *coefficients.shape[1:])


def sweep_hypotheses(coefficients: torch.Tensor, max_step_px: float = 1.0, stride: int = SWEEP_PROBE_STRIDE) -> int:
    """Number of hypotheses, uniform in s over [-1, 1], with neighbours at most ``max_step_px`` apart in
    the other half for every pixel of the per-pixel sweep polynomials ``coefficients`` (N, H, W, 2).

    The speed of the sweep (px per unit s) is probed at 257 values of s on every ``stride``-th row and column of
    the grid (the sweep varies slowly across the image; 1: every pixel given).

    Example:
        >>> rig = thesis_setup1().downscaled(8); fit = fit_sweep(rig, (400.0, 700.0))
        >>> uv = torch.stack(torch.meshgrid(torch.arange(64.0), torch.arange(96.0), indexing="xy"), -1)
        >>> coef = sweep_coefficients(fit, uv.double()).permute(2, 0, 1, 3)
        >>> sweep_hypotheses(coef) == sweep_hypotheses(coef[:, ::4, ::4], stride=1)
        True
    """
    if max_step_px <= 0:
        raise OptionError(f"max_step_px must be > 0, got {max_step_px}")
    check_int(stride, "stride", 1)
    probe = torch.linspace(-1.0, 1.0, 257, dtype=coefficients.dtype, device=coefficients.device)
    sub = coefficients[:, ::stride, ::stride]
    pos = positions_at(sub, probe)  # (257, h, w, 2)
    speed = (pos[1:] - pos[:-1]).norm(dim=-1).amax() * 256 / 2  # px per unit s (max over pixels)
    return max(2, math.ceil(float(speed) * 2 / max_step_px * 1.02) + 1)


def sweep_match(coefficients: torch.Tensor, s: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The per-pixel sweep polynomials (Chebyshev in s, :func:`~prismstereo.epipolar.sweep.sweep_coefficients`)
    at ``s`` and their slope d m / d s, on whole maps (Clenshaw's recurrence and its derivative).

    Args:
        coefficients: (N, 2, h, w) per-pixel coefficients.
        s: (B, 1, h, w) sweep coordinates in [-1, 1].

    Returns:
        (match, slope): (B, 2, h, w) each, positions in the other half (px of the polynomials' rig) and d/ds.

    Example:
        >>> c = torch.zeros(3, 2, 1, 1); c[1] = 1.0  # m(s) = T_1(s) = s
        >>> [t.flatten().tolist() for t in sweep_match(c, torch.full((1, 1, 1, 1), 0.5))]
        [[0.5, 0.5], [1.0, 1.0]]
    """
    check_shape(coefficients, ["N", 2, "H", "W"], "coefficients")
    terms = coefficients.unbind(0)  # one Split when exported, not a Slice per term
    two_s = 2.0 * s
    b1 = b2 = d1 = d2 = torch.zeros_like(terms[0] * s)
    for k in range(len(terms) - 1, 0, -1):  # Clenshaw: b_k = c_k + 2 s b_(k+1) - b_(k+2), and d/ds
        b1, b2, d1, d2 = terms[k] + two_s * b1 - b2, b1, 2.0 * b1 + two_s * d1 - d2, d1
    return terms[0] + s * b1 - b2, b1 + s * d1 - d2
