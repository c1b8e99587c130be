"""Plane-sweep cost volumes: warp the other half-image to the reference pixels once per hypothesis (one
``grid_sample`` call for all of them), then compare.

For a fronto-parallel depth plane the warped slice is the other half as seen from the reference view, so
window costs (census, ZNCC) compare like with like; for a coarse-to-fine band around a smooth prior
surface each slice is the warp by a surface parallel to that prior (a slanted support window).

Costs (lower is better), all (B, D, H, W):

* ``'sad'``: mean over channels of |I_ref - I_warped| per pixel (aggregate with a box afterwards);
  differentiable w.r.t. both images.
* ``'census'``: Hamming distance between the census codes (``window`` x ``window``, one bit per neighbour
  and channel: darker than the centre by more than ``census_threshold``) of the reference and of each
  warped slice, in [0, bits].
* ``'zncc'``: 1 - zero-normalised cross-correlation over the window (grey), in [0, 2]; differentiable.

Samples outside the other half or on its pixels that see nothing through the prism get the worst cost.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
import torch.nn.functional as F

from prismstereo.errors import OptionError, ShapeError, check_option, check_shape
from prismstereo.matching.aggregate import box_filter
from prismstereo.matching.cost import COSTS, Cost

__all__ = [
    "Warped", "flat_index", "sample_points", "sample_slices", "shift_cost", "sweep_cost", "warp_slices", "worst_cost",
]


class Warped(NamedTuple):
    """The other half-image resampled at every hypothesis.

    Attributes:
        image: (B, C, D, H, W) samples.
        valid: (B, D, H, W) bool: every bilinear tap lies inside the other half on a pixel that sees
            through the prism.
    """

    image: torch.Tensor
    valid: torch.Tensor


def sample_slices(other: torch.Tensor, grid: torch.Tensor, shared: bool | None = None) -> torch.Tensor:
    """Sample ``other`` at a plane-sweep grid with one bilinear ``grid_sample`` call (border padding).

    Args:
        other: (B, C, H_o, W_o) the other half-image.
        grid: (B or 1, D, H, W, 2) sample positions normalised for ``grid_sample`` (align_corners=False:
            -1 and +1 are the outer edges of the first and last pixel).
        shared: the grid (batch 1) serves every image: the images are stacked in the channel axis of one
            ``grid_sample`` call instead of copying the grid per image. None: when the grid's batch is 1. Pass
            it explicitly in code that is traced for ONNX export (a traced batch of 1 would fix the choice).

    Returns:
        (B, C, D, H, W) samples.

    Raises:
        ShapeError: bad shapes, or a shared grid with batch > 1.

    Example:
        >>> sample_slices(torch.rand(2, 3, 10, 12), torch.zeros(1, 4, 10, 8, 2)).shape
        torch.Size([2, 3, 4, 10, 8])
    """
    check_shape(other, ["B", "C", "H", "W"], "other")
    check_shape(grid, ["B", "D", "H", "W", 2], "grid")
    b = other.shape[0]
    h_o, w_o = other.shape[-2:]
    g = grid.to(other.dtype)
    if g.shape[0] not in (1, b):
        raise ShapeError(f"grid batch {g.shape[0]} must be 1 or the image batch {b}")
    _, d, h, w, _ = g.shape
    if shared is None:
        shared = g.shape[0] == 1
    # border padding: windows reaching past the edge see replicated pixels instead of black, which keeps
    # matches near the other half's edges (whether the sample itself is real is decided by the caller)
    if shared:  # one grid for the batch: the images go to the channel axis (no copy of the grid per image)
        if g.shape[0] != 1:
            raise ShapeError(f"a shared grid must have batch 1, got {g.shape[0]}")
        return F.grid_sample(other.reshape(1, -1, h_o, w_o), g.reshape(1, d * h, w, 2), mode="bilinear",
                             padding_mode="border", align_corners=False).view(b, -1, d, h, w)
    if g.shape[0] != b:  # (an Expand is a copy in onnxruntime: only when the grid really has batch 1)
        g = g.expand(b, -1, -1, -1, -1)
    return F.grid_sample(other, g.reshape(b, d * h, w, 2), mode="bilinear",
                         padding_mode="border", align_corners=False).view(b, -1, d, h, w)


def sample_points(image: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of ``image`` at per-image pixel positions (pixel centres at integers; positions outside
    are clamped to the image, which is ``grid_sample``'s border padding).

    Two implementations of the same interpolation, by runtime (measured on 11 x 768 x 512 positions in a
    768 x 512 image, 2 threads): torch eager calls ``grid_sample`` (13-20 ms); in an ONNX export the graph
    gathers each position's four taps (element gathers from four shifted views of the image, one index) and
    blends them, because onnxruntime's GridSample kernel is single-threaded and slow there (80-95 ms against
    ~50 ms for a gather form). The two agree to float rounding; both are differentiable w.r.t. the
    image and the positions.

    Args:
        image: (B, C, H, W).
        x, y: (B, D, H', W') column and row of each sample (the same shape).

    Returns:
        (B, C, D, H', W') samples.

    Raises:
        ShapeError: bad shapes.

    Example:
        >>> image = torch.arange(12.0).view(1, 1, 3, 4)
        >>> out = sample_points(image, torch.tensor([[[[0.5, 9.0]]]]), torch.tensor([[[[1.0, 0.0]]]]))
        >>> [round(v, 4) for v in out.flatten().tolist()]  # (0.5, 1) between 4 and 5; (9, 0) clamped to (3, 0)
        [4.5, 3.0]
    """
    check_shape(image, ["B", "C", "H", "W"], "image")
    check_shape(x, ["B", "D", "H", "W"], "x")
    if y.shape != x.shape or x.shape[0] != image.shape[0]:
        raise ShapeError(f"x {tuple(x.shape)} and y {tuple(y.shape)} must match, with the image's batch "
                         f"{image.shape[0]}")
    h, w = image.shape[-2:]
    x, y = x.to(image.dtype), y.to(image.dtype)
    if not torch.onnx.is_in_onnx_export():
        return sample_slices(image, torch.stack([(2.0 * x + 1.0) / w - 1.0, (2.0 * y + 1.0) / h - 1.0], -1),
                             shared=False)
    return _gather_bilinear(image, x, y)


def _gather_bilinear(image: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """:func:`sample_points` by element gathers of the four taps (its ONNX form): onnxruntime's GatherElements
    copies elements in a typed loop, its Gather one memcpy per row (a (H W, 4) table of pixel quads gathered
    by rows: 5.1 ms for 1.2 M samples against 3.9 ms for the four element gathers, micro-benchmark). The taps are
    gathered from the top-left pixel and three difference images of the bilinear form, and a one-channel image
    from ``_GATHER_ROWS`` copies, so that onnxruntime spreads each gather over its threads. The
    narrow-range pyramid at 1024 x 768 in onnxruntime (paired A/B): the difference form 0.99x, the rows 0.94x."""
    b, c, h, w = image.shape
    d, hs, ws = x.shape[1:]
    x, y = x.clamp(0.0, w - 1.0), y.clamp(0.0, h - 1.0)
    x0, y0 = x.detach().floor(), y.detach().floor()
    wx, wy = (x - x0).unsqueeze(1), (y - y0).unsqueeze(1)
    padded = F.pad(image, (0, 1, 0, 1), mode="replicate")  # taps right of / below the last pixel weigh 0
    # NaN positions (a NaN image upstream) cast to garbage: clamped they read a pixel and stay NaN through the
    # weights, where onnxruntime would abort the whole frame on an out-of-range index
    n = d * hs * ws
    rows = _GATHER_ROWS if c == 1 and n % _GATHER_ROWS == 0 else 1  # see _GATHER_ROWS
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
    thread, ~4x slower, and gathers with it ~30 % slower; torch takes either), computed in floating point where
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


def warp_slices(
    other: torch.Tensor, grid: torch.Tensor, other_valid: torch.Tensor | None = None, shared: bool | None = None
) -> Warped:
    """Sample ``other`` at a plane-sweep grid (:func:`sample_slices`) and flag the real samples.

    A sample is valid when it lies between the first and last pixel centres of ``other`` (all bilinear taps
    inside, 1e-3 px slack) and, with ``other_valid``, every tap with non-zero weight is a pixel that sees
    through the prism (the mask is sampled as an extra channel of the same call).

    Args:
        other: (B, C, H_o, W_o) the other half-image.
        grid: (B or 1, D, H, W, 2) normalised sample positions (see :func:`sample_slices`).
        other_valid: optional (H_o, W_o) bool, pixels of the other half that see through the prism.
        shared: see :func:`sample_slices`.

    Returns:
        Warped.

    Example:
        >>> w = warp_slices(torch.rand(2, 1, 10, 12), torch.zeros(1, 3, 10, 8, 2))
        >>> w.image.shape, w.valid.shape
        (torch.Size([2, 1, 3, 10, 8]), torch.Size([2, 3, 10, 8]))
    """
    check_shape(other, ["B", "C", "H", "W"], "other")
    check_shape(grid, ["B", "D", "H", "W", 2], "grid")
    b, c = other.shape[:2]
    h_o, w_o = other.shape[-2:]
    g = grid.to(other.dtype)
    x, y = ((g[..., 0] + 1) * w_o - 1) / 2, ((g[..., 1] + 1) * h_o - 1) / 2  # pixel coordinates
    eps = 1e-3  # px: a centre exactly on the last pixel must not fall out by rounding
    inside = (x >= -eps) & (x <= w_o - 1 + eps) & (y >= -eps) & (y <= h_o - 1 + eps)
    stacked = other if other_valid is None else torch.cat([other, other_valid.to(other).expand(b, 1, -1, -1)], 1)
    sampled = sample_slices(stacked, g, shared)
    valid = inside if other_valid is None else inside & (sampled[:, c] > 0.999)
    return Warped(sampled[:, :c], valid.expand(b, -1, -1, -1))


def worst_cost(cost: Cost, channels: int, window: int) -> float:
    """The largest value of a cost: the fill for invalid samples.

    Example:
        >>> worst_cost("census", 1, 5)
        24.0
    """
    check_option(cost, COSTS, "cost")
    return {"sad": 1.0, "zncc": 2.0, "census": float(channels * (window * window - 1))}[cost]


_VAR_FLOOR = 1e-5  # (0.8 / 255)^2: below the variance of 8-bit read noise of 1 level


_box = box_filter  # (B, D, H, W) window mean, separable
# onnxruntime's GatherElements runs the rows of its index (all axes before the gathered one) on its threads and one
# row on one thread: the bilinear taps gather from the image repeated on this many rows (a Concat, a copy of the
# image), the samples split between them (micro-benchmark, 2 M samples from a 768 x 512 image, 2 threads, the copy
# included: 1 row 1.07 ms, 2 rows 0.67 ms, 4 rows 0.73 ms, 8 rows 0.96 ms). One-channel images (the grey samples of
# ZNCC); images of several channels gather on one row per channel
_GATHER_ROWS = 2


def _fill(volume: torch.Tensor, valid: torch.Tensor, value: float, bounded: bool = False) -> torch.Tensor:
    """``volume`` where ``valid`` (broadcastable bool), ``value`` elsewhere. In an ONNX export the fill is a
    scalar constant of the Where: onnxruntime took 6.8 ms on (1, 11, 768, 512) against a full tensor of the
    fill (a ConstantOfShape per call), ~2-4 ms less with the scalar (torch eager keeps a full tensor: its
    broadcasting Where is slower there). ``bounded``: the caller guarantees 0 <= volume <= value, so the fill is
    max(volume, value * not valid), bitwise the same; exported that is Not, Cast, Mul and Max, which onnxruntime
    runs multi-threaded where its Where runs on one thread (~1.5 ns per element)."""
    if torch.onnx.is_in_onnx_export():
        if bounded:
            return torch.maximum(volume, valid.logical_not().to(volume.dtype) * value)
        return torch.where(valid, volume, volume.new_tensor(value))
    return torch.where(valid, volume, torch.full_like(volume, value))


def _census(reference: torch.Tensor, warped: torch.Tensor, window: int, threshold: float) -> torch.Tensor:
    r = window // 2
    h, w = reference.shape[-2:]
    centre_r = reference.unsqueeze(2) - threshold  # (B, C, 1, H, W)
    centre_w = warped - threshold
    pad_ref = F.pad(reference, (r, r, r, r), mode="replicate").unsqueeze(2)
    pad_w = F.pad(warped, (r, r, r, r, 0, 0), mode="replicate")
    count = None
    for dy in range(window):
        for dx in range(window):
            if (dy, dx) == (r, r):
                continue
            differ = torch.logical_xor(pad_ref[..., dy:dy + h, dx:dx + w] < centre_r,
                                       pad_w[..., dy:dy + h, dx:dx + w] < centre_w).to(warped.dtype)
            count = differ if count is None else count + differ
    return count.sum(1) if count.shape[1] > 1 else count.squeeze(1)  # over channels once, at the end


def _grey(x: torch.Tensor) -> torch.Tensor:
    """Channel mean, keeping the channel axis (no ReduceMean, a copy in onnxruntime, for one channel)."""
    return x if x.shape[1] == 1 else x.mean(1, keepdim=True)


def _moments(x: torch.Tensor, window: int) -> tuple[torch.Tensor, torch.Tensor]:
    if x.shape[1] == 1:  # one plane: x and x^2 in one box (onnxruntime pools a channel on one thread: 2 for 1)
        mean, square = _box(torch.cat([x, x * x], 1), window).split(1, 1)
    else:
        mean, square = _box(x, window), _box(x * x, window)
    return mean, (square - mean * mean).clamp_min(0)


def _ncc_cost(cross: torch.Tensor, var_r: torch.Tensor, var_w: torch.Tensor) -> torch.Tensor:
    # regularised by ~ the variance of 8-bit noise: windows without texture (e.g. the black pixels outside the
    # prism's view) get NCC ~ 0 instead of a ratio of rounding errors (torch and onnxruntime differed by 0.02)
    ncc = cross / torch.sqrt((var_r + _VAR_FLOOR) * (var_w + _VAR_FLOOR))
    return 1.0 - ncc.clamp(-1, 1)


def _zncc(reference: torch.Tensor, warped: torch.Tensor, window: int) -> torch.Tensor:
    # centred on 0.5 (ZNCC is offset-invariant): E[x^2] - E[x]^2 then cancels far less in float32, which keeps
    # torch and onnxruntime within ~1e-6 of each other on low-contrast windows
    ref = _grey(reference) - 0.5  # (B, 1, H, W)
    wrp = _grey(warped).squeeze(1) - 0.5  # (B, D, H, W)
    mean_r, var_r = _moments(ref, window)
    mean_w, var_w = _moments(wrp, window)
    cross = _box(wrp * ref, window) - mean_w * mean_r
    return _ncc_cost(cross, var_r, var_w)


def sweep_cost(
    reference: torch.Tensor, warped: Warped, cost: Cost = "census", window: int = 5, census_threshold: float = 0.0
) -> torch.Tensor:
    """Per-pixel matching cost of the reference half against each warped slice.

    Args:
        reference: (B, C, H, W) reference half in [0, 1].
        warped: :func:`warp_slices` of the other half, image (B, C, D, H, W).
        cost: 'sad', 'zncc' or 'census'.
        window: census / ZNCC window (odd; census >= 3).
        census_threshold: a census bit is set where the neighbour is darker than the centre by more than this
            (>= 0). A threshold that is not a multiple of 1/255 keeps 8-bit ties (equal neighbours) from
            flipping bits on rounding differences between runtimes (torch vs onnxruntime).

    Returns:
        (B, D, H, W) cost, the worst value (:func:`worst_cost`) where the sample is not valid.

    Raises:
        OptionError: unknown cost, bad window or negative threshold. ShapeError: reference and slices disagree.

    Example:
        >>> ref = torch.rand(1, 1, 12, 16)
        >>> slices = Warped(ref.unsqueeze(2).repeat(1, 1, 3, 1, 1), torch.ones(1, 3, 12, 16, dtype=torch.bool))
        >>> float(sweep_cost(ref, slices, "census").abs().max())
        0.0
    """
    check_option(cost, COSTS, "cost")
    check_shape(reference, ["B", "C", "H", "W"], "reference")
    check_shape(warped.image, ["B", "C", "D", "H", "W"], "warped.image")
    if not isinstance(window, int) or window < 1 or window % 2 == 0 or (cost == "census" and window < 3):
        raise OptionError(f"window must be an odd int (>= 3 for census), got {window!r}")
    if warped.image.shape[:2] != reference.shape[:2] or warped.image.shape[-2:] != reference.shape[-2:]:
        raise ShapeError(f"reference {tuple(reference.shape)} does not match slices {tuple(warped.image.shape)}")
    if not census_threshold >= 0:
        raise OptionError(f"census_threshold must be >= 0, got {census_threshold}")
    if cost == "census":
        volume = _census(reference, warped.image, window, census_threshold)
    elif cost == "sad":
        volume = (reference.unsqueeze(2) - warped.image).abs().mean(1)
    else:
        volume = _zncc(reference, warped.image, window)
    # ZNCC (1 - a clamped NCC) and census counts lie in [0, worst]; SAD only for images in [0, 1]
    return _fill(volume, warped.valid, worst_cost(cost, reference.shape[1], window), bounded=cost != "sad")


def shift_cost(
    reference: torch.Tensor,
    other: torch.Tensor,
    index: torch.Tensor,
    valid: torch.Tensor,
    cost: Cost = "census",
    window: int = 5,
    census_threshold: float = 0.0,
    transposed: bool = False,
    fill: float | None = None,
) -> torch.Tensor:
    """Cost volume of a rectified pair by column shifts: hypothesis d compares reference column u with
    column ``index[d, u]`` of ``other`` on the same row (one gather builds the slices).

    Same costs and values as :func:`sweep_cost` on the gathered slices, except that ZNCC takes the window
    moments of ``other`` once from the image and gathers them (a box of a shifted image is the shifted box):
    one box filter over the volume instead of three. The window // 2 columns at each side of the reference,
    whose windows are cut by its edge, are computed from the gathered slices as :func:`sweep_cost` does;
    ``other``'s moments see its edge columns replicated, as the clamped gather (and ``grid_sample``'s border
    padding) does.

    The work happens on the transposed images (columns as rows): gathering whole rows of H values is a plain
    copy, where gathering single columns into a (D, H, W) layout cost onnxruntime 35 ms + an 11 ms transpose
    at 95 x 193 x 128 x 3. ``transposed=True`` returns that (B, D, W, H) layout as it is: box filters,
    semi-global aggregation over 2, 4 or 8 directions and the winner search are symmetric in H and W, so a
    caller can stay transposed until it has a per-pixel result.

    Args:
        reference: (B, C, H, W) rectified reference in [0, 1].
        other: (B, C, H, W_o) rectified other image.
        index: (D, W) long, columns of ``other`` (in [0, W_o)).
        valid: (B or 1, D, H, W) bool, real samples ((B or 1, D, W, H) with ``transposed``).
        cost: 'sad', 'zncc' or 'census'.
        window: census / ZNCC window (odd).
        census_threshold: see :func:`sweep_cost`.
        transposed: return (B, D, W, H).
        fill: the cost of entries that are not valid (>= 0); None: the worst cost (:func:`worst_cost`).

    Returns:
        (B, D, H, W) cost (or (B, D, W, H)), ``fill`` where not valid.

    Raises:
        OptionError / ShapeError: as :func:`sweep_cost`; an index or mask of the wrong shape.

    Example:
        >>> ref = torch.rand(1, 1, 8, 12); other = torch.roll(ref, 2, dims=-1)
        >>> index = (torch.arange(12) + torch.arange(4).view(-1, 1)).clamp(max=11)
        >>> vol = shift_cost(ref, other, index, torch.ones(1, 4, 8, 12, dtype=torch.bool), "sad")
        >>> int(vol[..., :10].mean((0, 2, 3)).argmin())
        2
    """
    check_option(cost, COSTS, "cost")
    check_shape(reference, ["B", "C", "H", "W"], "reference")
    check_shape(other, ["B", "C", "H", "W"], "other")
    check_shape(index, ["D", "W"], "index")
    b, _, h, w = reference.shape
    if index.shape[1] != w or other.shape[:3] != reference.shape[:3]:
        raise ShapeError(f"reference {tuple(reference.shape)}, other {tuple(other.shape)} and index "
                         f"{tuple(index.shape)} disagree")
    d = index.shape[0]
    expected = (d, w, h) if transposed else (d, h, w)
    if valid.dim() != 4 or tuple(valid.shape[1:]) != expected or valid.shape[0] not in (1, b):
        raise ShapeError(f"valid must be (B or 1, {', '.join(map(str, expected))}), got {tuple(valid.shape)}")
    valid_t = (valid if transposed else valid.transpose(-1, -2)).expand(b, -1, -1, -1)
    ref_t, other_t = reference.transpose(-1, -2), other.transpose(-1, -2)  # (B, C, W, H): columns as rows

    def gather(image_t: torch.Tensor) -> torch.Tensor:  # (B, C, W_o, H) -> (B, C, D, W, H)
        return image_t[:, :, index]

    if fill is not None and not (isinstance(fill, (int, float)) and fill >= 0):
        raise OptionError(f"fill must be a number >= 0 or None, got {fill!r}")
    if cost != "zncc":
        volume = sweep_cost(ref_t, Warped(gather(other_t), valid_t), cost, window, census_threshold)
        if fill is not None:  # sweep_cost filled the worst cost
            volume = _fill(volume, valid_t, float(fill))
        return volume if transposed else volume.transpose(-1, -2)
    if not isinstance(window, int) or window < 1 or window % 2 == 0:
        raise OptionError(f"window must be an odd int, got {window!r}")
    r = window // 2
    ref = _grey(ref_t) - 0.5
    oth = _grey(other_t) - 0.5
    mean_r, var_r = _moments(ref, window)
    # the gather clamps columns, i.e. replicates the edge columns: so do the moments' windows
    mean_o, var_o = (m[..., r:r + oth.shape[-2], :] for m in _moments(F.pad(oth, (0, 0, r, r), mode="replicate"),
                                                                       window))
    # three gathers of (B, W_o, H) images: one of the stacked three cost onnxruntime a 7 ms Split of the
    # (B, 3, D, W, H) result, and dropping a channel axis after the gather is another copy (2.3 ms)
    wrp, mean_w, var_w = (x[:, 0][:, index] for x in (oth, mean_o, var_o))  # each (B, D, W, H)
    cross = _box(wrp * ref, window) - mean_w * mean_r
    volume = _ncc_cost(cross, var_r, var_w)
    if r and w > 2 * r:  # edge columns: truncated windows on both sides, as sweep_cost computes them
        left = _zncc(ref_t[..., :2 * r, :], wrp[..., :2 * r, :].unsqueeze(1) + 0.5, window)[..., :r, :]
        right = _zncc(ref_t[..., -2 * r:, :], wrp[..., -2 * r:, :].unsqueeze(1) + 0.5, window)[..., -r:, :]
        volume = torch.cat([left, volume[..., r:w - r, :], right], -2)
    worst = worst_cost("zncc", 1, window)
    value = worst if fill is None else float(fill)  # ZNCC lies in [0, worst]: a fill >= worst is max(volume, fill)
    volume = _fill(volume, valid_t, value, bounded=value >= worst)
    return volume if transposed else volume.transpose(-1, -2)
