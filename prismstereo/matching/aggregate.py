"""Cost aggregation: a box filter over the whole volume, and semi-global matching (SGM) scanline passes.

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

from prismstereo.errors import OptionError, ShapeError, check_shape

__all__ = ["box_filter", "box_std", "sgm_aggregate", "sgm_aggregate_guided"]

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

    Two implementations of the same mean, by runtime (each the fastest measured there; numbers in
    ``docs/design.md``, *Implementation measurements*). Torch eager adds, in place, each slice's neighbours 1..r
    rows away on both sides (no padding), then the same along W, and multiplies by the reciprocal pixel count, a
    separable (row count x column count) map; an ONNX export gets one AveragePool (count_include_pad=0). The
    forms agree to float rounding.

    Example:
        >>> box_filter(torch.ones(1, 3, 8, 8), 5).shape
        torch.Size([1, 3, 8, 8])
        >>> float(box_filter(torch.arange(16.0).view(1, 1, 4, 4), 3)[0, 0, 0, 0])  # mean of 0, 1, 4, 5
        2.5
    """
    check_shape(volume, ["B", "D", "H", "W"], "volume")
    if not isinstance(window, int) or window < 1 or window % 2 == 0:
        raise OptionError(f"window must be a positive odd int, got {window!r}")
    if window == 1:
        return volume
    r = window // 2
    if torch.onnx.is_in_onnx_export():
        return F.avg_pool2d(volume, window, stride=1, padding=r, count_include_pad=False)
    h, w = volume.shape[-2:]
    rows = volume.clone()
    for i in range(1, min(r, h - 1) + 1):  # each row gains its neighbours i rows below and above
        rows[..., i:, :].add_(volume[..., :h - i, :])
        rows[..., :h - i, :].add_(volume[..., i:, :])
    sums = rows.clone()
    for i in range(1, min(r, w - 1) + 1):
        sums[..., i:].add_(rows[..., :w - i])
        sums[..., :w - i].add_(rows[..., i:])
    return sums.mul_(1.0 / (_counts(h, r, volume).view(-1, 1) * _counts(w, r, volume)))


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


def _counts(n: int, r: int, like: torch.Tensor) -> torch.Tensor:
    """Pixels of a 2 r + 1 window centred on each of n positions that lie inside [0, n)."""
    i = torch.arange(n, device=like.device)
    return (i.clamp(max=r) + (n - 1 - i).clamp(max=r) + 1).to(like.dtype)


def _neighbour_max(q: torch.Tensor) -> torch.Tensor:
    """max(q(d - 1), q(d + 1)) over the hypothesis axis 2 of (N, 1, D, X) (one neighbour at the ends); in an
    ONNX export max(q(d - 1), q(d), q(d + 1)), the same inside :func:`_scan`."""
    if torch.onnx.is_in_onnx_export():
        return F.max_pool2d(q, (3, 1), stride=1, padding=(1, 0))
    return torch.cat([q[:, :, 1:2], torch.maximum(q[:, :, :-2], q[:, :, 2:]), q[:, :, -2:-1]], 2)


def _scan(volume: torch.Tensor, p1: float, p2: float, shift: int = 0,
          p2s: torch.Tensor | None = None) -> torch.Tensor:
    """One forward scan along axis 0 of ``volume`` = -C (S, N, D, X) in negated form; returns -L_r, same shape.
    ``p2s``: optional (S, N, 1, X) jump penalties (into each slice).

    Negated, the recursion is Q(p) = -C(p) + max(Q_n, N(Q_n) - P1, -P2) with Q_n = Q(p - r) - max_d Q(p - r)
    the predecessor normalised to a maximum of 0 and N the neighbours' maximum max(Q_n(d - 1), Q_n(d + 1)) (the
    same numbers as max(Q', N(Q') - P1, M - P2) - M up to rounding; normalised first, the P2 term is a Clip at
    -P2, one graph node less). In an ONNX export N is one MaxPool over 3 hypotheses (it also covers d itself,
    which cannot win there since P1 >= 0): 7 graph nodes per scan step (ReduceMax, Sub, MaxPool, Sub, Max,
    Clip, Add; ONNX has a MaxPool, no MinPool). The slices are taken along axis 0 with one Split and the steps
    concatenated back along it (no Reshape, Squeeze or Unsqueeze per step); the alternatives measured are in
    ``docs/design.md`` (*Implementation measurements*). Differentiable torch eager keeps the Slice / Maximum /
    Concat form (its max_pool2d also computes indices, ~5x slower per step); without autograd
    :func:`_scan_eager` computes the same values faster (the same operations in the same order: bitwise). A
    ``shift`` of 1 makes the scan diagonal: the predecessor of position x in a slice is x - 1 in the previous
    slice.
    """
    s, n, d, x = volume.shape
    # rank-changing Reshapes (to 5-D and back) before the Split: onnxruntime's transpose optimizer cannot push the
    # orienting Transposes through them (it folded them into a strided Split along the last axis: 5 ms instead of
    # ~0.5), and the Split yields the 4-D slices directly (a Reshape per slice before: one graph node per scan step
    # more; without them the scans of the narrow range's coarse volume, (1, 28, 192, 128), took 0.95x the time)
    slices = volume.reshape(s, 1, n, d, x).reshape(s, n, d, x).split(1, dim=0)
    floors = None if p2s is None else (-p2s).reshape(s, 1, n, 1, x).reshape(s, n, 1, x).split(1, dim=0)
    starts = _starts(volume, shift)
    out = [slices[0]]
    for i in range(1, len(slices)):
        prev = out[-1]
        if shift:  # diagonal: position x continues the path of x - 1 in the previous slice
            prev = torch.roll(prev, shifts=shift, dims=-1)  # positions without a predecessor are reset below
        prev = prev - prev.amax(dim=2, keepdim=True)  # amax: max(dim) also computes indices, ~1000x slower here
        best = torch.maximum(prev, _neighbour_max(prev) - p1)
        best = best.clamp_min(-p2) if floors is None else torch.maximum(best, floors[i])
        cur = slices[i] + best
        if shift:
            cur = torch.where(starts, cur, slices[i])
        out.append(cur)
    return torch.cat(out, dim=0)


def _scan_eager(volume: torch.Tensor, p1: float, p2: float, shift: int = 0,
                p2s: torch.Tensor | None = None) -> torch.Tensor:
    """:func:`_scan` (same arguments) without autograd, same values bitwise: (S, N, D, X), a view of one
    preallocated (S, N, D + 2, X) buffer whose rows 0 and D + 1 are -inf. Each step writes into its slice of the
    buffer, and the neighbours' maximum of the previous step is one ``maximum`` of its rows shifted by +-1 (no
    Concat per step, no concatenation of the steps at the end)."""
    s, n, d, x = volume.shape
    out = volume.new_empty(s, n, d + 2, x)
    out[:, :, 0].fill_(float("-inf"))
    out[:, :, d + 1].fill_(float("-inf"))
    out[0, :, 1:d + 1].copy_(volume[0])
    starts = _starts(volume, shift)
    floors = None if p2s is None else -p2s
    for i in range(1, s):
        c, cur, padded = volume[i], out[i, :, 1:d + 1], out[i - 1]
        if shift:  # diagonal: position x continues the path of x - 1 in the previous slice
            padded = torch.roll(padded, shifts=shift, dims=-1)  # positions without a predecessor: reset below
        padded = padded - padded[:, 1:d + 1].amax(dim=1, keepdim=True)  # the -inf rows stay -inf
        prev = padded[:, 1:d + 1]
        best = torch.maximum(prev, torch.maximum(padded[:, :d], padded[:, 2:]).sub_(p1))
        best = best.clamp_min_(-p2) if floors is None else torch.maximum(best, floors[i], out=best)
        torch.add(c, best, out=cur)
        if shift:
            cur.copy_(torch.where(starts, cur, c))
    return out[:, :, 1:d + 1]


def _starts(like: torch.Tensor, shift: int) -> torch.Tensor:
    """(X,) positions of a slice that have a predecessor in a scan with this ``shift`` (0 or 1)."""
    return torch.arange(like.shape[-1], device=like.device) >= shift


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
    in torch eager the scans are :func:`_scan_eager` and the sums are taken in place.

    Measured on the 1/8-resolution coarse volume of a 1024 x 768 frame ((1, 49, 64, 97), 4 directions,
    2 threads, medians of 20 alternating runs): onnxruntime 13.0-14.3 -> 10.4-10.9 ms (half the graph nodes:
    161 scan steps instead of 322), torch eager 11-18 -> 7-8 ms. Stacking all four directions into one scan
    of max(H, W) steps (zero-padding the vertical volume to square) was no faster in onnxruntime: 1.5x the
    elements per step outweighed the fewer nodes (~2 us each); on the narrow range's coarse volume
    (1, 28, 192, 128): 192 steps instead of 320, 1.17x the time.
    """
    fast = not torch.onnx.is_in_onnx_export() and not (torch.is_grad_enabled() and negated.requires_grad)
    scan = _scan_eager if fast else _scan
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
    # Transpose(Add(w, Transpose(h))), whose inner Transpose swaps the first and last axes (1.6 ms on one thread
    # for the (64, 1, 49, 97) sum of a 1024 x 768 frame, against 0.06 ms for each of the two written here); it
    # cannot move Transposes through the rank-changing Reshapes
    flat = (b, negated.shape[1], -1)
    return (along_w.reshape(flat) + along_h.reshape(flat)).view(negated.shape)


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
