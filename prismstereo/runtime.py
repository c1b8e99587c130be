"""The runtime-dependent forms of the layers: what torch eager runs, and what goes into a traced / ONNX graph
instead, side by side, one function per operation.

Every operation here computes the same numbers in both forms (to float rounding, the SGM scan and the fills
bitwise); each form is the faster one in its runtime (torch eager on CPU, onnxruntime). The algorithms
(:mod:`~prismstereo.matching.cost`, :mod:`~prismstereo.matching.aggregate`, :mod:`~prismstereo.matching.sweep_cost`,
:mod:`~prismstereo.matching.search`, :mod:`~prismstereo.matching.band`) call these and never test the runtime
themselves; the tests hold the two forms equal. Layers whose exported form is a different arrangement of the same
algorithm (the power series of :mod:`~prismstereo.epipolar.series`, the table gathers of
:mod:`~prismstereo.epipolar.sweep_table`, the model's batching) ask :func:`exporting` /
:func:`tracing` here.

* :func:`fill_invalid`: invalid entries of a volume -> a value (a full tensor vs a scalar constant, or a Max).
* :func:`box_mean`: window mean (in-place shifted sums vs one AveragePool).
* :func:`box_max`: window maximum (shifted maxima vs two MaxPools).
* :func:`scan_traced` / :func:`scan_eager`: one SGM scan (Concat of steps vs a preallocated buffer).
* :func:`sample_bilinear`: bilinear samples at pixel positions (``grid_sample`` vs element gathers); its eager form,
  :func:`sample_grid` (bilinear samples at normalised positions, border padding), is the package's one bilinear
  ``grid_sample``, which the plane-sweep slices and the rectified level's resampling call in both runtimes.
* :func:`scatter_min`: a scatter with a minimum (``scatter_reduce`` vs one ScatterElements).
* :func:`crop`: the top-left (h, w) of a map (a view in eager; exported, a Slice only along an axis that is longer).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

__all__ = ["GATHER_ROWS", "box_max", "box_mean", "crop", "exporting", "fill_invalid", "flat_index",
           "gather_bilinear", "in_place", "sample_bilinear", "sample_grid", "scan_eager", "scan_traced",
           "scatter_min", "tracing"]

# onnxruntime's GatherElements runs the rows of its index (all axes before the gathered one) on its threads and one
# row on one thread: the bilinear taps gather from the image repeated on this many rows (a Concat, a copy of the
# image), the samples split between them. Two rows keep two threads busy; more rows copy the image more often than
# they gain (the GatherElements row of ``benchmarks/onnx_speed.py``'s profile). One-channel images (the grey samples
# of ZNCC); images of several channels gather on one row per channel
GATHER_ROWS = 2


def exporting() -> bool:
    """True while ``torch.onnx.export`` traces the graph: the exported forms are taken.

    Example:
        >>> exporting()
        False
    """
    return torch.onnx.is_in_onnx_export()


def tracing() -> bool:
    """True under ``torch.jit.trace`` or an ONNX export: shapes are symbolic, sizes must not be baked in.

    Example:
        >>> tracing()
        False
    """
    return torch.jit.is_tracing() or torch.onnx.is_in_onnx_export()


def in_place(t: torch.Tensor) -> bool:
    """Torch eager without autograd through ``t``: buffers may be written in place.

    Example:
        >>> in_place(torch.zeros(2)), in_place(torch.zeros(2, requires_grad=True))
        (True, False)
    """
    return not exporting() and not (torch.is_grad_enabled() and t.requires_grad)


def crop(t: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """The top-left ``h`` x ``w`` of a (..., H, W) map with H >= h and W >= w, sliced only along an axis longer than
    asked: in torch eager a slice is a view either way, but an exported Slice copies the map even when it keeps all
    of it (a binned map whose size k divides, the interpolation of a level back onto the size it came from).

    Example:
        >>> crop(torch.zeros(1, 1, 5, 4), 4, 4).shape
        torch.Size([1, 1, 4, 4])
    """
    if t.shape[-2] > h:
        t = t[..., :h, :]
    return t[..., :w] if t.shape[-1] > w else t


def fill_invalid(volume: torch.Tensor, valid: torch.Tensor, value: float, bounded: bool = False) -> torch.Tensor:
    """``volume`` where ``valid`` (broadcastable bool), ``value`` elsewhere.

    Exported, the fill is a scalar constant of the Where: a full tensor of the fill is a ConstantOfShape per call,
    which onnxruntime's Where then reads element by element (torch eager keeps a full tensor: its broadcasting
    Where is the slower one there). ``bounded``: the caller guarantees 0 <= volume <= value, so the fill is
    max(volume, value * not valid), bitwise the same; exported that is Not, Cast, Mul and Max, which onnxruntime
    runs multi-threaded where its Where runs on one thread.

    Example:
        >>> fill_invalid(torch.tensor([0.2, 0.4]), torch.tensor([True, False]), 1.0).tolist()
        [0.20000000298023224, 1.0]
    """
    if exporting():
        if bounded:
            return torch.maximum(volume, valid.logical_not().to(volume.dtype) * value)
        return torch.where(valid, volume, volume.new_tensor(value))
    return torch.where(valid, volume, torch.full_like(volume, value))


def box_mean(volume: torch.Tensor, window: int) -> torch.Tensor:
    """Mean over a ``window`` x ``window`` box (odd, > 1) of every slice of a (B, D, H, W) volume, pixels inside
    the image only. Torch eager adds, in place, each slice's neighbours 1..r rows away on both sides (no padding),
    then the same along W, and multiplies by the reciprocal pixel count, a separable (row count x column count)
    map; exported it is one AveragePool (count_include_pad=0).

    Example:
        >>> float(box_mean(torch.arange(9.0).view(1, 1, 3, 3), 3)[0, 0, 0, 0])  # mean of 0, 1, 3, 4
        2.0
    """
    r = window // 2
    if exporting():
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


def box_max(volume: torch.Tensor, window: int) -> torch.Tensor:
    """Maximum over a ``window`` x ``window`` box (odd, > 1) of every slice of a (B, D, H, W) volume, pixels inside
    the image only; separable (rows, then columns). Torch eager takes the maximum with each slice's neighbours
    1..r rows away on both sides, then the same along W (2 window - 2 maxima over shifted views: torch's
    ``max_pool2d``, even as two 1-D pools, also computes indices and is much slower); exported, and where gradients
    are recorded, it is two MaxPools.

    Example:
        >>> box_max(torch.arange(9.0).view(1, 1, 3, 3), 3)[0, 0, 0].tolist()
        [4.0, 5.0, 5.0]
    """
    r = window // 2
    if not in_place(volume):
        return F.max_pool2d(F.max_pool2d(volume, (window, 1), 1, (r, 0)), (1, window), 1, (0, r))
    h, w = volume.shape[-2:]
    rows = volume.clone()
    for i in range(1, min(r, h - 1) + 1):
        torch.maximum(rows[..., i:, :], volume[..., :h - i, :], out=rows[..., i:, :])
        torch.maximum(rows[..., :h - i, :], volume[..., i:, :], out=rows[..., :h - i, :])
    out = rows.clone()
    for i in range(1, min(r, w - 1) + 1):
        torch.maximum(out[..., i:], rows[..., :w - i], out=out[..., i:])
        torch.maximum(out[..., :w - i], rows[..., i:], out=out[..., :w - i])
    return out


def _counts(n: int, r: int, like: torch.Tensor) -> torch.Tensor:
    """Pixels of a 2 r + 1 window centred on each of n positions that lie inside [0, n)."""
    i = torch.arange(n, device=like.device)
    return (i.clamp(max=r) + (n - 1 - i).clamp(max=r) + 1).to(like.dtype)


def _neighbour_max(q: torch.Tensor) -> torch.Tensor:
    """max(q(d - 1), q(d + 1)) over the hypothesis axis 2 of (N, 1, D, X) (one neighbour at the ends); exported
    max(q(d - 1), q(d), q(d + 1)), the same inside :func:`scan_traced`."""
    if exporting():
        return F.max_pool2d(q, (3, 1), stride=1, padding=(1, 0))
    return torch.cat([q[:, :, 1:2], torch.maximum(q[:, :, :-2], q[:, :, 2:]), q[:, :, -2:-1]], 2)


def scan_traced(volume: torch.Tensor, p1: float, p2: float, shift: int = 0,
                p2s: torch.Tensor | None = None) -> torch.Tensor:
    """One forward SGM scan along axis 0 of ``volume`` = -C (S, N, D, X) in negated form; returns -L_r, same shape.
    The exported and differentiable form (:func:`scan_eager` is the in-place one). ``p2s``: optional
    (S, N, 1, X) jump penalties (into each slice); a ``shift`` of 1 makes the scan diagonal: the predecessor of
    position x in a slice is x - 1 in the previous slice.

    Negated, the recursion is Q(p) = -C(p) + max(Q_n, N(Q_n) - P1, -P2) with Q_n = Q(p - r) - max_d Q(p - r)
    the predecessor normalised to a maximum of 0 and N the neighbours' maximum max(Q_n(d - 1), Q_n(d + 1)) (the
    same numbers as max(Q', N(Q') - P1, M - P2) - M up to rounding; normalised first, the P2 term is a Clip at
    -P2, one graph node less). Exported, N is one MaxPool over 3 hypotheses (it also covers d itself, which
    cannot win there since P1 >= 0): 7 graph nodes per scan step (ReduceMax, Sub, MaxPool, Sub, Max, Clip, Add;
    ONNX has a MaxPool, no MinPool). The slices are taken along axis 0 with one Split and the steps concatenated
    back along it (no Reshape, Squeeze or Unsqueeze per step). Differentiable torch eager keeps the Slice /
    Maximum / Concat form (its max_pool2d also computes indices, a slower step).

    Example:
        >>> scan_traced(-torch.rand(4, 1, 3, 5), 0.1, 0.5).shape
        torch.Size([4, 1, 3, 5])
    """
    s, n, d, x = volume.shape
    # rank-changing Reshapes (to 5-D and back) before the Split: onnxruntime's transpose optimizer cannot push the
    # orienting Transposes through them (it folded them into a strided Split along the last axis, which copies
    # element by element), and the Split yields the 4-D slices directly (a Reshape per slice would be one graph
    # node per scan step more)
    slices = volume.reshape(s, 1, n, d, x).reshape(s, n, d, x).split(1, dim=0)
    floors = None if p2s is None else (-p2s).reshape(s, 1, n, 1, x).reshape(s, n, 1, x).split(1, dim=0)
    starts = _starts(volume, shift)
    out = [slices[0]]
    for i in range(1, len(slices)):
        prev = out[-1]
        if shift:  # diagonal: position x continues the path of x - 1 in the previous slice
            prev = torch.roll(prev, shifts=shift, dims=-1)  # positions without a predecessor are reset below
        prev = prev - prev.amax(dim=2, keepdim=True)  # amax: max(dim) also computes indices
        best = torch.maximum(prev, _neighbour_max(prev) - p1)
        best = best.clamp_min(-p2) if floors is None else torch.maximum(best, floors[i])
        cur = slices[i] + best
        if shift:
            cur = torch.where(starts, cur, slices[i])
        out.append(cur)
    return torch.cat(out, dim=0)


def scan_eager(volume: torch.Tensor, p1: float, p2: float, shift: int = 0,
               p2s: torch.Tensor | None = None) -> torch.Tensor:
    """:func:`scan_traced` (same arguments) without autograd, same values bitwise: (S, N, D, X), a view of one
    preallocated (S, N, D + 2, X) buffer whose rows 0 and D + 1 are -inf. Each step writes into its slice of the
    buffer, and the neighbours' maximum of the previous step is one ``maximum`` of its rows shifted by +-1 (no
    Concat per step, no concatenation of the steps at the end).

    Example:
        >>> volume = -torch.rand(4, 1, 3, 5)
        >>> torch.equal(scan_eager(volume, 0.1, 0.5), scan_traced(volume, 0.1, 0.5))
        True
    """
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


def sample_bilinear(image: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of (B, C, H, W) at (B, D, H', W') pixel positions, clamped to the image: (B, C, D, H', W').

    Torch eager calls ``grid_sample``; exported the graph gathers each position's four taps
    (:func:`gather_bilinear`), because onnxruntime's GridSample kernel is single-threaded and slower there than
    the gathers (``benchmarks/onnx_speed.py --sampling`` times the sweep sampling in both runtimes).

    Example:
        >>> image = torch.arange(12.0).view(1, 1, 3, 4)
        >>> sample_bilinear(image, torch.tensor([[[[0.5]]]]), torch.tensor([[[[1.0]]]])).flatten().tolist()
        [4.5]
    """
    if exporting():
        return gather_bilinear(image, x, y)
    b, h, w = image.shape[0], *image.shape[-2:]
    d, hs, ws = x.shape[1:]
    grid = torch.stack([(2.0 * x + 1.0) / w - 1.0, (2.0 * y + 1.0) / h - 1.0], -1)
    return sample_grid(image, grid.reshape(b, d * hs, ws, 2)).view(b, -1, d, hs, ws)


def sample_grid(image: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of (B, C, H, W) at (B, H', W', 2) positions normalised as ``grid_sample``'s
    (align_corners=False: -1 and +1 are the outer edges of the first and last pixel), border padding: (B, C, H', W').
    One ``grid_sample`` (a GridSample node when exported) in both runtimes.

    Example:
        >>> sample_grid(torch.arange(4.0).view(1, 1, 2, 2), torch.zeros(1, 1, 1, 2)).item()  # the centre
        1.5
    """
    return F.grid_sample(image, grid, mode="bilinear", padding_mode="border", align_corners=False)


def gather_bilinear(image: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """:func:`sample_bilinear` by element gathers of the four taps (its exported form, runnable eagerly).

    onnxruntime's GatherElements copies elements in a typed loop, its Gather one memcpy per row, and a (H W, 4)
    table of pixel quads gathered by rows lost to the four element gathers. The taps are gathered from the
    top-left pixel and three difference images of the bilinear form, and a one-channel image from
    :data:`GATHER_ROWS` copies, so that onnxruntime spreads each gather over its threads (both timed on the narrow
    range's pyramid at 1024 x 768 by ``benchmarks/onnx_speed.py``).

    Example:
        >>> image, x, y = torch.rand(1, 1, 6, 8), 7 * torch.rand(1, 2, 3, 3), 5 * torch.rand(1, 2, 3, 3)
        >>> torch.allclose(gather_bilinear(image, x, y), sample_bilinear(image, x, y), atol=1e-6)
        True
    """
    b, c, h, w = image.shape
    d, hs, ws = x.shape[1:]
    x, y = x.clamp(0.0, w - 1.0), y.clamp(0.0, h - 1.0)
    x0, y0 = x.detach().floor(), y.detach().floor()
    wx, wy = (x - x0).unsqueeze(1), (y - y0).unsqueeze(1)
    padded = F.pad(image, (0, 1, 0, 1), mode="replicate")  # taps right of / below the last pixel weigh 0
    # NaN positions (a NaN image upstream) cast to garbage: clamped they read a pixel and stay NaN through the
    # weights, where onnxruntime would abort the whole frame on an out-of-range index
    n = d * hs * ws
    rows = GATHER_ROWS if c == 1 and n % GATHER_ROWS == 0 else 1
    index = flat_index(y0, x0, w, h * w).view(b, rows, n // rows)
    index = index if c == 1 else index.expand(b, c, -1)  # an Expand is a copy in onnxruntime
    # the four taps of every sample share one index into four (H, W) images of the padded one: the top-left tap
    # and the differences of the bilinear form p00 + wx dx + wy (dy + wx dxy), taken once per image, so that the
    # volume takes 6 passes after the gathers instead of 9 (three lerps); one image on ``rows`` rows by a Concat
    # (an Expand to the dynamic batch exports with a Where on its shape)
    p00, p01, p10, p11 = (padded[..., :-1, :-1], padded[..., :-1, 1:], padded[..., 1:, :-1], padded[..., 1:, 1:])
    dx = p01 - p00
    taps = (p00, dx, p10 - p00, p11 - p10 - dx)
    a, gx, gy, gxy = (torch.cat([tap.reshape(b, c, h * w)] * rows, 1).gather(2, index).view(b, c, d, hs, ws)
                      for tap in taps)
    return a + wx * gx + wy * (gy + wx * gxy)


def flat_index(row: torch.Tensor, column: torch.Tensor, width: int, size: int) -> torch.Tensor:
    """Flat index ``row * width + column`` of whole-numbered floating-point rows and columns into an image of
    ``size`` pixels, for gathers and scatters: int32 where it fits (onnxruntime casts and clamps int64 on one
    thread, and gathers with it more slowly; torch takes either), computed in floating point where
    that is exact (``size`` <= 2 / eps: 2^24 in float32) and cast once, and clamped to [0, size): a NaN position
    (a NaN image upstream), cast to garbage, still indexes a pixel, where onnxruntime would abort the whole
    frame on an out-of-range index.

    Args:
        row, column: (*) whole numbers (floor or round first), the same shape and floating dtype.
        width: pixels per row.
        size: pixels in the image.

    Returns:
        (*) int32 (int64 for images of 2^31 pixels or more).

    Example:
        >>> flat_index(torch.tensor([0.0, 2.0, float("nan")]), torch.tensor([3.0, 1.0, 0.0]), 4, 12).tolist()
        [3, 9, 0]
    """
    index_type = torch.int32 if size < 2**31 else torch.long
    if size <= 2 / torch.finfo(row.dtype).eps:
        index = (row * width + column).to(index_type)
    else:
        index = row.to(index_type) * width + column.to(index_type)
    return index.clamp(0, size - 1)


def scatter_min(data: torch.Tensor, index: torch.Tensor, updates: torch.Tensor) -> torch.Tensor:
    """``data.scatter_reduce(1, index, updates, "amin")``: in an exported graph one ScatterElements with reduction
    'min' (the exporter's own form wraps it in an If whose branch copies all three inputs on every frame).

    Args:
        data: (B, N) the values before the scatter.
        index: (B, M) integer positions in [0, N).
        updates: (B, M) the values scattered; each position keeps the smallest.

    Returns:
        (B, N).

    Example:
        >>> scatter_min(torch.full((1, 3), 9.0), torch.tensor([[0, 0, 2]]), torch.tensor([[5.0, 4.0, 7.0]]))
        tensor([[4., 9., 7.]])
    """
    if exporting():
        return _ScatterMin.apply(data, index, updates)
    return data.scatter_reduce(1, index, updates, reduce="amin")


class _ScatterMin(torch.autograd.Function):
    """:func:`scatter_min`'s exported form: one ScatterElements (reduction 'min')."""

    @staticmethod
    def forward(ctx, data: torch.Tensor, index: torch.Tensor, updates: torch.Tensor) -> torch.Tensor:  # noqa: D102
        return data.scatter_reduce(1, index, updates, reduce="amin")

    @staticmethod
    def symbolic(g, data, index, updates):  # noqa: D102
        return g.op("ScatterElements", data, index, updates, axis_i=1, reduction_s="min")
