"""Cost aggregation: a box filter over the whole volume, the guided filter (cost-volume filtering), and
semi-global matching (SGM) scanline passes.

SGM (Hirschmueller 2008) adds, for each scan direction r, the path cost
L_r(p, d) = C(p, d) + min(L_r(p - r, d), L_r(p - r, d +- 1) + P1, min_k L_r(p - r, k) + P2) - min_k L_r(p - r, k)
and sums the paths. P1 penalises one-hypothesis changes between neighbours, P2 larger jumps. Each pass
is vectorised over the batch, the hypotheses and the other image axis; only the scan itself loops.
:func:`sgm_aggregate_guided` lowers P2 across intensity edges of a guide image (Hirschmueller's adaptive
P2), where depth discontinuities usually are.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from prismstereo.errors import OptionError, ShapeError, check_int, check_odd, check_shape
from prismstereo.runtime import box_mean, in_place, scan_eager, scan_traced

__all__ = ["box_filter", "box_std", "guided_filter", "sgm_aggregate", "sgm_aggregate_guided"]

# the guided filter's radius, regularisation and subsampling (chosen on Middlebury): the defaults of the 'guided'
# aggregation's options (prismstereo.matching.options.AggregationConfig), which the depth model and the rectified
# matcher share
GUIDED_RADIUS, GUIDED_EPS, GUIDED_SUBSAMPLE = 13, 1e-4, 2

# (scan dim, reverse, row shift of the predecessor): dim 3 scans columns, dim 2 rows; a shift of +-1 makes
# the horizontal scan diagonal (the predecessor of row y is row y - shift of the previous column)
_DIRECTIONS = {
    2: ((3, False, 0), (3, True, 0)),
    4: ((3, False, 0), (3, True, 0), (2, False, 0), (2, True, 0)),
    8: ((3, False, 0), (3, True, 0), (2, False, 0), (2, True, 0),
        (3, False, 1), (3, False, -1), (3, True, 1), (3, True, -1)),
}


def box_filter(volume: torch.Tensor, window: int) -> torch.Tensor:
    """Mean over a ``window`` x ``window`` box of every slice of a (B, D, H, W) volume, over the whole volume at
    once (borders average the pixels inside the image only).

    Torch eager and an ONNX export compute it in different forms that agree to float rounding
    (:func:`~prismstereo.runtime.box_mean`: in-place shifted sums vs one AveragePool).

    Example:
        >>> box_filter(torch.ones(1, 3, 8, 8), 5).shape
        torch.Size([1, 3, 8, 8])
        >>> float(box_filter(torch.arange(16.0).view(1, 1, 4, 4), 3)[0, 0, 0, 0])  # mean of 0, 1, 4, 5
        2.5
    """
    check_shape(volume, ["B", "D", "H", "W"], "volume")
    check_odd(window, "window")
    if window == 1:
        return volume
    return box_mean(volume, window)


def box_std(image: torch.Tensor, window: int) -> torch.Tensor:
    """Standard deviation of a (B, 1, H, W) image over a ``window`` x ``window`` box around every pixel (borders:
    the pixels inside), from one :func:`box_filter` of the image and its square (in float32 the difference of
    the two moments leaves ~1e-4 on a constant image in [0, 1], ~1/40 of a grey level).

    Example:
        >>> float(box_std(torch.tensor([[[[0.0, 2.0, 0.0, 2.0]]]]), 3)[0, 0, 0, 1])  # 0, 2, 0: mean 2/3
        0.9428090453147888
    """
    check_shape(image, ["B", 1, "H", "W"], "image")
    mean, square = box_filter(torch.cat([image, image * image], 1), window).split(1, 1)
    # floored at 1e-12 before the root: a flat window's std is 1e-6 and its gradient 0, not infinite
    return (square - mean * mean).clamp_min(1e-12).sqrt()


def _flips(reverse: bool, shift: int) -> list[int]:
    """Axes of an oriented (S, B, C, X) volume to flip: S for a reverse scan, X for a shift of -1."""
    return ([0] if reverse else []) + ([3] if shift < 0 else [])


def _orient(t: torch.Tensor, dim: int, reverse: bool, shift: int) -> torch.Tensor:
    """(B, C, H, W) -> (S, B, C, X) such that the scan (``dim``, ``reverse``, ``shift``) runs forward along S
    with a shift of 0 or 1: S = W, X = H for ``dim`` 3, S = H, X = W for ``dim`` 2; a reverse scan flips S and
    a shift of -1 flips X."""
    t = t.permute(3, 0, 1, 2) if dim == 3 else t.permute(2, 0, 1, 3)
    flips = _flips(reverse, shift)
    return t.flip(flips) if flips else t


def _paths(negated: torch.Tensor, p1: float, p2: float, directions: int,
           p2_maps: list[torch.Tensor] | None = None) -> torch.Tensor:
    """Sum of the scan paths of ``directions`` over ``negated`` = -C (B, D, H, W), negated form; ``p2_maps``
    optional (B, 1, H, W) jump penalties per direction (in ``_DIRECTIONS`` order).

    The scans of one shape run at once: each direction's volume is oriented so that its scan runs forward
    along the first axis (:func:`_orient`) and the directions along one axis are stacked on the batch axis, so
    one scan computes both horizontal paths, one both vertical ones, and one the four diagonal ones (8
    directions; those with a shift of -1 flipped to +1). The paths along one axis are summed in their oriented
    layout (the W-axis ones in ``_DIRECTIONS`` order), the two sums transposed back and added. Without autograd
    in torch eager the scans are :func:`~prismstereo.runtime.scan_eager` and the sums are taken in place.

    Stacking the directions of one axis halves the graph nodes of the exported scans (one scan step per slice
    for both directions) and the scan calls in eager. Stacking all four directions into one scan of max(H, W)
    steps (zero-padding the vertical volume to square) was not kept: the padded elements per step outweigh the
    fewer nodes in onnxruntime. ``benchmarks/onnx_speed.py`` times the coarse levels that run these scans.
    """
    fast = in_place(negated)
    scan = scan_eager if fast else scan_traced
    chosen = _DIRECTIONS[directions]
    b = negated.shape[0]
    sums: dict[int, torch.Tensor] = {}  # per scanned axis, in its oriented (S, B, D, X) layout
    for kind in dict.fromkeys((dim, bool(shift)) for dim, _, shift in chosen):  # same-shape groups
        group = [i for i, (dim, _, shift) in enumerate(chosen) if (dim, bool(shift)) == kind]
        stacked = torch.cat([_orient(negated, *chosen[i]) for i in group], 1)
        p2s = None
        if p2_maps is not None:
            p2s = torch.cat([_orient(p2_maps[i].expand(b, -1, -1, -1), *chosen[i]) for i in group], 1)
        out = scan(stacked, p1, p2, 1 if chosen[group[0]][2] else 0, p2s)
        for k, i in enumerate(group):
            dim, reverse, shift = chosen[i]
            path = out[:, k * b:(k + 1) * b]
            flips = _flips(reverse, shift)
            path = path.flip(flips) if flips else path
            if dim not in sums:
                sums[dim] = path  # in eager summed in place: into the scan's own buffer
            else:
                sums[dim] = sums[dim].add_(path) if fast else sums[dim] + path
    along_w = sums[3].permute(1, 2, 3, 0)  # (W, B, D, H) -> (B, D, H, W)
    if 2 not in sums:
        return along_w.contiguous() if fast else along_w
    along_h = sums[2].permute(1, 2, 0, 3)  # (H, B, D, W) -> (B, D, H, W)
    if fast:
        return torch.add(along_w, along_h, out=torch.empty_like(negated, memory_format=torch.contiguous_format))
    # added as (B, D, H W): onnxruntime's transpose optimizer turned Add(Transpose(w), Transpose(h)) into
    # Transpose(Add(w, Transpose(h))), whose inner Transpose swaps the first and last axes, on one thread and far
    # slower than the two written here; it cannot move Transposes through the rank-changing Reshapes
    flat = (b, negated.shape[1], -1)
    return (along_w.reshape(flat) + along_h.reshape(flat)).view(negated.shape)


def guided_filter(
    volume: torch.Tensor, guide: torch.Tensor, radius: int = GUIDED_RADIUS, eps: float = GUIDED_EPS, subsample: int = 1
) -> torch.Tensor:
    """He et al.'s guided filter of every slice of a (B, D, H, W) cost volume (Rhemann et al. 2011's
    cost-volume filtering): an edge-aware mean that smooths the cost inside regions of similar colour of the
    guide and little across its edges, so the aggregation window does not fatten foreground objects.

    Each slice p is modelled as a_k . I + b_k in every (2 r + 1)^2 window k of the guide I (C channels): a_k =
    (Sigma_k + eps Id)^-1 cov_k(I, p), b_k = mean_k(p) - a_k . mean_k(I); the output averages the models of
    the windows covering a pixel, q = mean(a) . I + mean(b). Windows are cut at the image border (box means
    over the pixels inside, :func:`box_filter`); 2 + 2 C box filters of the
    volume's size. With ``subsample`` s > 1 the coefficients are computed on s x s block means of the volume
    and the guide with a radius of round(r / s) and bilinearly upsampled (He & Sun's fast guided filter,
    ~1 / s^2 of the work); q still uses the full-resolution guide, so the edges stay sharp.

    Args:
        volume: (B, D, H, W) cost, finite.
        guide: (B or 1, C, H, W) guide image (e.g. the reference image in [0, 1]).
        radius: box radius r (>= 1), in full-resolution pixels (default :data:`GUIDED_RADIUS`, 13).
        eps: regularisation (> 0, squared guide units): a window whose guide varies less than ~sqrt(eps) is
            averaged like a box (default :data:`GUIDED_EPS`, 1e-4).
        subsample: s (>= 1), 1 for the exact filter (``AggregationConfig`` defaults to :data:`GUIDED_SUBSAMPLE`).

    Returns:
        (B, D, H, W) filtered volume, dtype of ``volume``.

    Raises:
        ShapeError: bad shapes. OptionError: radius or subsample not an int >= 1, or eps <= 0.

    Example:
        >>> guide = torch.zeros(1, 1, 8, 8); guide[..., 4:] = 1.0  # two regions
        >>> cost = torch.zeros(1, 1, 8, 8); cost[..., 4:] = 2.0
        >>> out = guided_filter(cost + 0.1 * torch.rand(1, 1, 8, 8), guide, 2, 1e-4)
        >>> bool((out[..., :4] < 0.2).all() and (out[..., 4:] > 1.9).all())  # the step survives
        True
    """
    check_shape(volume, ["B", "D", "H", "W"], "volume")
    check_shape(guide, ["B", "C", "H", "W"], "guide")
    if guide.shape[-2:] != volume.shape[-2:] or guide.shape[0] not in (1, volume.shape[0]):
        raise ShapeError(f"guide {tuple(guide.shape)} must match the volume {tuple(volume.shape)} in H, W and "
                         "batch")
    for name, value in (("radius", radius), ("subsample", subsample)):
        check_int(value, name, 1)
    if not eps > 0:
        raise OptionError(f"eps must be > 0, got {eps!r}")
    guide = guide.to(volume.dtype)
    full = guide
    if subsample > 1:
        guide = F.avg_pool2d(guide, subsample, ceil_mode=True)
        volume = F.avg_pool2d(volume, subsample, ceil_mode=True)
    window = 2 * max(1, round(radius / subsample)) + 1
    b, d, h, w = volume.shape
    c = guide.shape[1]
    mean_i = box_filter(guide, window)  # (Bg, C, h, w)
    mean_p = box_filter(volume, window)
    mean_ip = box_filter(torch.cat([guide[:, i:i + 1] * volume for i in range(c)], 1), window).view(b, c, d, h, w)
    cov_ip = mean_ip - mean_i.unsqueeze(2) * mean_p.unsqueeze(1)  # (B, C, D, h, w)
    if c == 1:  # a grey guide: a = cov / (var + eps), no matrix to build and invert
        var_i = box_filter(guide * guide, window) - mean_i * mean_i + eps  # (Bg, 1, h, w)
        a = cov_ip / var_i.unsqueeze(2)
    else:
        pairs = [(i, j) for i in range(c) for j in range(i, c)]
        corr = box_filter(torch.cat([guide[:, i:i + 1] * guide[:, j:j + 1] for i, j in pairs], 1), window)
        sigma = guide.new_empty(guide.shape[0], h, w, c, c)
        for k, (i, j) in enumerate(pairs):
            cov = corr[:, k] - mean_i[:, i] * mean_i[:, j] + (eps if i == j else 0.0)
            sigma[..., i, j] = cov
            sigma[..., j, i] = cov
        inverse = torch.linalg.inv(sigma).permute(0, 3, 4, 1, 2).unsqueeze(3)  # (Bg, C, C, 1, h, w)
        a = torch.stack([sum(inverse[:, i, j] * cov_ip[:, j] for j in range(c)) for i in range(c)], 1)
    coefficients = torch.cat([box_filter(a.reshape(b, c * d, h, w), window),
                              box_filter(mean_p - (a * mean_i.unsqueeze(2)).sum(1), window)], 1)
    if subsample > 1:
        coefficients = F.interpolate(coefficients, size=full.shape[-2:], mode="bilinear", align_corners=False)
    mean_a = coefficients[:, :c * d].unflatten(1, (c, d))
    return (mean_a * full.unsqueeze(2)).sum(1) + coefficients[:, c * d:]


def sgm_aggregate(cost: torch.Tensor, p1: float, p2: float, directions: int = 4) -> torch.Tensor:
    """Semi-global aggregation of a (B, D, H, W) cost volume along 2 (horizontal), 4 (plus vertical) or 8
    (plus diagonal) scanline directions; returns the sum of the path costs, same shape.

    Args:
        cost: (B, D, H, W), lower is better, finite.
        p1: penalty for a change of one hypothesis between neighbours (>= 0).
        p2: penalty for larger changes (>= p1).
        directions: 2, 4 or 8.

    Example:
        >>> sgm_aggregate(torch.rand(1, 8, 10, 12), 0.5, 2.0).shape
        torch.Size([1, 8, 10, 12])
    """
    check_shape(cost, ["B", "D", "H", "W"], "cost")
    if directions not in _DIRECTIONS:
        raise OptionError(f"directions must be one of {sorted(_DIRECTIONS)}, got {directions!r}")
    if not 0 <= p1 <= p2:
        raise OptionError(f"need 0 <= p1 <= p2, got p1={p1}, p2={p2}")
    return -_paths(-cost, p1, p2, directions)


def sgm_aggregate_guided(
    cost: torch.Tensor, guide: torch.Tensor, p1: float, p2: float, edge: float, directions: int = 8
) -> torch.Tensor:
    """Semi-global aggregation whose jump penalty drops across intensity edges of ``guide``.

    Like :func:`sgm_aggregate`, but the penalty for a jump of more than one hypothesis between a pixel p and
    its predecessor q on a path is ``max(p1, p2 / (1 + |I_p - I_q| / edge))`` (largest over the guide's
    channels): full P2 inside uniform regions, down to P1 across strong edges, where depth discontinuities
    usually are (Hirschmueller 2008's intensity-adaptive P2).

    Args:
        cost: (B, D, H, W), lower is better, finite.
        guide: (B, C, H, W) the reference image (same H, W; batch B or 1).
        p1: penalty for a change of one hypothesis between neighbours (>= 0).
        p2: penalty for larger changes inside uniform regions (>= p1).
        edge: intensity step (guide units, > 0) that halves P2.
        directions: 2, 4 or 8.

    Returns:
        (B, D, H, W) sum of the path costs.

    Raises:
        ShapeError: bad shapes. OptionError: bad penalties, edge or directions.

    Example:
        >>> guide = torch.zeros(1, 1, 10, 12); guide[..., 6:] = 1.0
        >>> sgm_aggregate_guided(torch.rand(1, 8, 10, 12), guide, 0.5, 2.0, 0.05).shape
        torch.Size([1, 8, 10, 12])
    """
    check_shape(cost, ["B", "D", "H", "W"], "cost")
    check_shape(guide, ["B", "C", "H", "W"], "guide")
    if guide.shape[-2:] != cost.shape[-2:] or guide.shape[0] not in (1, cost.shape[0]):
        raise ShapeError(f"guide {tuple(guide.shape)} must match the cost {tuple(cost.shape)} in H, W and batch")
    if directions not in _DIRECTIONS:
        raise OptionError(f"directions must be one of {sorted(_DIRECTIONS)}, got {directions!r}")
    if not 0 <= p1 <= p2:
        raise OptionError(f"need 0 <= p1 <= p2, got p1={p1}, p2={p2}")
    if not edge > 0:
        raise OptionError(f"edge must be > 0, got {edge}")
    guide = guide.to(cost.dtype)
    p2_maps = []
    for dim, reverse, shift in _DIRECTIONS[directions]:
        # predecessor of (y, x) on this path: (y - dy, x - dx); roll wraps only where there is none
        step = -1 if reverse else 1
        dy, dx = (shift, step) if dim == 3 else (step, shift)
        before = torch.roll(guide, shifts=(dy, dx), dims=(2, 3))
        jump = (guide - before).abs().amax(dim=1, keepdim=True)
        p2_maps.append((p2 / (1 + jump / edge)).clamp_min(p1))
    return -_paths(-cost, p1, p2, directions, p2_maps)
