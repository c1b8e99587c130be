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

__all__ = ["box_filter", "sgm_aggregate", "sgm_aggregate_guided"]

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

    Two implementations of the same mean, by runtime. Torch eager adds, in place, each slice's neighbours
    1..r rows away on both sides (no padding), then the same along W, and multiplies by the reciprocal pixel
    count, a separable (row count x column count) map. Measured on a (1, 11, 76, 512) strip of the fine band,
    k = 7: 0.39 / 0.43 ms at 1 / 2 threads, where two depthwise 1-D convolutions of ones (the previous form)
    took 1.09 / 1.75 ms (oneDNN's depthwise convolution got slower with a second thread; 78 boxes per
    1024 x 768 frame) and avg_pool2d with count_include_pad=False ~10x longer. In an ONNX export the graph
    gets one AveragePool (count_include_pad=0), which onnxruntime runs in 3.9 ms on a (1, 11, 768, 512)
    volume (separable pools 5.9 ms, depthwise convolutions 7.3 ms). The forms agree to float rounding.

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


def _counts(n: int, r: int, like: torch.Tensor) -> torch.Tensor:
    """Pixels of a 2 r + 1 window centred on each of n positions that lie inside [0, n)."""
    i = torch.arange(n, device=like.device)
    return (i.clamp(max=r) + (n - 1 - i).clamp(max=r) + 1).to(like.dtype)


def _neighbour_max(q: torch.Tensor) -> torch.Tensor:
    """max(q(d - 1), q(d + 1)) over the hypothesis axis 2 of (B, 1, D, X) (one neighbour at the ends); in an
    ONNX export max(q(d - 1), q(d), q(d + 1)), the same inside :func:`_scan`."""
    if torch.onnx.is_in_onnx_export():
        return F.max_pool2d(q, (3, 1), stride=1, padding=(1, 0))
    return torch.cat([q[:, :, 1:2], torch.maximum(q[:, :, :-2], q[:, :, 2:]), q[:, :, -2:-1]], 2)


def _scan(
    slices: tuple[torch.Tensor, ...],
    p1: float,
    p2: float,
    reverse: bool,
    shift: int = 0,
    p2s: tuple[torch.Tensor, ...] | None = None,
) -> torch.Tensor:
    """One scan direction in negated form over ``slices``, the (B, 1, D, X) slices -C of a volume along the
    scanned axis; returns -L_r stacked along axis 3, (B, 1, D, N, X). ``p2s``: optional (B, 1, 1, X) per-slice
    jump penalties (into that slice).

    Negated, the recursion is Q(p) = -C(p) + max(Q', N(Q') - P1, M - P2) - M with Q' = Q(p - r),
    M = max_d Q' and N the neighbours' maximum max(Q'(d - 1), Q'(d + 1)). In an ONNX export N is one MaxPool
    over 3 hypotheses (it also covers d itself, which cannot win there since P1 >= 0): 8 graph nodes per scan
    step instead of 13 (ONNX has a MaxPool, no MinPool), export 24 -> 10 s and ~30 ms less per onnxruntime
    frame at 1024 x 768. Differentiable torch eager keeps the Slice / Maximum / Concat form (its max_pool2d
    also computes indices: 100 us per step against 20 us); without autograd :func:`_scan_eager` computes the
    same values faster. The values are bitwise those of the plain recursion (negation is exact; min, max and
    the same additions in the same order). A ``shift`` of +-1 makes the scan diagonal: the predecessor of
    position x in a slice is x - shift in the previous slice.
    """
    order = range(len(slices) - 1, -1, -1) if reverse else range(len(slices))
    out: list[torch.Tensor] = [slices[0].new_empty(0)] * len(slices)
    prev = None
    starts = _starts(slices[0], shift)
    for i in order:
        c = slices[i]
        if prev is None:
            cur = c
        else:
            if shift:  # diagonal: row y continues the path of row y - shift in the previous column
                prev = torch.roll(prev, shifts=shift, dims=-1)  # rows without a predecessor are reset below
            big = prev.amax(dim=2, keepdim=True)  # amax: max(dim) also computes indices, ~1000x slower here
            near = _neighbour_max(prev)
            jump = p2 if p2s is None else p2s[i]
            cur = c + torch.maximum(torch.maximum(prev, near - p1), big - jump) - big
            if shift:
                cur = torch.where(starts, cur, c)
        out[i] = cur
        prev = cur
    return torch.stack(out, dim=3)


def _scan_eager(slices: tuple[torch.Tensor, ...], p1: float, p2: float, reverse: bool, shift: int = 0,
                p2s: tuple[torch.Tensor, ...] | None = None) -> torch.Tensor:
    """:func:`_scan` (same arguments) without autograd, same values bitwise: (B, 1, D, N, X), a view of one preallocated
    (B, 1, D + 2, N, X) buffer whose rows 0 and D + 1 are -inf. Each step writes into its slice of the buffer,
    and the neighbours' maximum of the previous step is one ``maximum`` of its rows shifted by +-1 (no Concat
    per step, no stack of the N steps at the end). Measured on a (1, 95, 193, 128) volume, 4 directions,
    2 threads, with the contiguous W-axis slices and in-place sums of :func:`_paths`: 62 -> 48 ms (the
    coarse level of a 1024 x 768 frame)."""
    b, _, d, x = slices[0].shape
    n = len(slices)
    out = slices[0].new_empty(b, 1, d + 2, n, x)
    out[:, :, 0].fill_(float("-inf"))
    out[:, :, d + 1].fill_(float("-inf"))
    order = range(n - 1, -1, -1) if reverse else range(n)
    starts = _starts(slices[0], shift)
    last = None
    for i in order:
        c, cur = slices[i], out[:, :, 1:d + 1, i]
        if last is None:
            cur.copy_(c)
        else:
            padded = out[:, :, :, last]
            if shift:  # diagonal: row y continues the path of row y - shift in the previous column
                padded = torch.roll(padded, shifts=shift, dims=-1)  # rows without a predecessor: reset below
            prev = padded[:, :, 1:d + 1]
            big = prev.amax(dim=2, keepdim=True)
            near = torch.maximum(padded[:, :, :d], padded[:, :, 2:])
            jump = p2 if p2s is None else p2s[i]
            torch.add(c, torch.maximum(torch.maximum(prev, near - p1), big - jump), out=cur).sub_(big)
            if shift:
                cur.copy_(torch.where(starts, cur, c))
        last = i
    return out[:, :, 1:d + 1]


def _starts(like: torch.Tensor, shift: int) -> torch.Tensor:
    """(X,) positions of a slice that have a predecessor in a diagonal scan with this ``shift``."""
    rows = torch.arange(like.shape[-1], device=like.device)
    return (rows >= shift) if shift >= 0 else (rows < rows.shape[0] + shift)


def _paths(negated: torch.Tensor, p1: float, p2: float, directions: int,
           p2_maps: list[torch.Tensor] | None = None) -> torch.Tensor:
    """Sum of the scan paths of ``directions`` over ``negated`` = -C (B, 1, D, H, W), negated form; ``p2_maps``
    optional (B, 1, H, W) jump penalties per direction (in ``_DIRECTIONS`` order).

    The directions along one axis share one slicing of the volume (one Split instead of one per direction:
    onnxruntime takes ~7 ms to split a (95, 128, 193) volume along its last axis), and the scans along W stack
    their slices on axis 3 of the volume transposed to (B, 1, D, W, H), then transpose the sum back once
    (stacking along the last axis is a strided copy, ~6 ms per direction there, the transpose ~2.6 ms).
    (onnxruntime's transpose optimizer folds the input-side transpose into the Split, which stays strided.)
    The sum keeps the order of ``_DIRECTIONS`` for 2 and 4 directions (bitwise as one path after the other);
    8 directions add the diagonal (W-axis) paths before the vertical ones. In torch eager without autograd the
    scans are :func:`_scan_eager`, the transposed volume is made contiguous once, and the paths are summed in
    place into the scans' own buffers (each fresh volume-sized sum costs page faults); the same values.
    """
    fast = not torch.onnx.is_in_onnx_export() and not (torch.is_grad_enabled() and negated.requires_grad)
    scan = _scan_eager if fast else _scan

    def add(acc: torch.Tensor | None, path: torch.Tensor) -> torch.Tensor:  # in place into our own buffers
        return path if acc is None else acc.add_(path) if fast else acc + path

    total = None
    for dim in (3, 2):  # the scanned axis of (B, D, H, W): 3 = along W (rows), 2 = along H (columns)
        chosen = [(i, reverse, shift) for i, (d, reverse, shift) in enumerate(_DIRECTIONS[directions]) if d == dim]
        if not chosen:
            continue
        volume = negated.transpose(3, 4) if dim == 3 else negated
        if dim == 3 and fast:  # contiguous slices (a fresh transposed copy; strided slices made each step slow)
            volume = volume.contiguous()
        slices = volume.unbind(3)
        acc = None
        for i, reverse, shift in chosen:
            p2s = None
            if p2_maps is not None:
                p2_map = p2_maps[i].unsqueeze(1)  # (B, 1, 1, H, W)
                p2s = (p2_map.transpose(3, 4) if dim == 3 else p2_map).unbind(3)
            path = scan(slices, p1, p2, reverse, shift, p2s)
            if dim == 3:
                acc = add(acc, path)
            else:
                total = add(total, path)
        if acc is not None:
            total = add(total, acc.transpose(3, 4))
    return total


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
    return -_paths(-cost.unsqueeze(1), p1, p2, directions).squeeze(1)


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
    return -_paths(-cost.unsqueeze(1), p1, p2, directions, p2_maps).squeeze(1)
