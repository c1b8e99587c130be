"""The temporal prior's options and data: what a video's frames are tracked with between key frames.

:class:`TemporalOptions` are the temporal band's options and the key-frame rules of
:class:`~prismstereo.stream.DepthStream`; :class:`BandPrior` is a prior at the band's resolution (the clipped inverse
depth, in which the sweep coordinate is affine, and where it places the band); :func:`band_prior` makes one from a
full-resolution result (a key frame's); :class:`TrackedDepth` is what a tracker returns. The band itself is
:class:`~prismstereo.classical.temporal.TemporalDepth` (torch) or its exported graph
(:class:`~prismstereo.export.OnnxDepth`); this module is what both share, light enough for a process that runs
only the graphs: it imports without torch, and :func:`band_prior` of numpy arrays runs in numpy.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any, Literal, NamedTuple

import numpy as np

from prismstereo.errors import OptionError, ShapeError, check_int, check_number, check_option, check_shape

if TYPE_CHECKING:  # imported for tensors: a process that runs exported graphs on arrays never imports torch
    import torch

__all__ = ["TEMPORAL_BAND_EDGES", "BandPrior", "TemporalOptions", "TrackedDepth", "band_prior"]

BandEdges = Literal["reject", "clamp"]
TEMPORAL_BAND_EDGES: tuple[str, ...] = ("reject", "clamp")


@dataclasses.dataclass(frozen=True, kw_only=True)
class TemporalOptions:
    """The temporal prior's options (JSON-friendly; :meth:`to_dict` / ``TemporalOptions(**d)``).

    Attributes:
        band: R: the band around the prior has 2 R + 1 hypotheses (>= 1).
        band_edges: a pixel whose best hypothesis is on the band's edge: invalid ('reject') or refined from the
            edge's inner neighbour, up to the edge ('clamp', default: no winner search, and on small moving
            sequences more coverage).
        reach: invalid prior pixels within this many pixels of valid ones take their mean sweep coordinate (>= 0).
        min_prior_confidence: prior pixels less confident than this count as invalid ones, in [0, 1].
        keyframe_interval: the full model at least every this many frames (>= 1; 1: every frame).
        cut_threshold: a scene cut: the mean absolute grey difference to the previous frame (8 x 8 block means,
            grey in [0, 1]) above this; the frame gets the full model.
        max_invalid_growth: the full model when the share of the reference half invalid in the prior exceeds the
            last key frame's by more than this (a depth step entering the view, occlusions), in [0, 1].
        min_valid_ratio: a tracked frame whose valid share falls below this times the last key frame's is
            computed again by the full model, in [0, 1] (0: never).
        extrapolate: the prior is the last depth extrapolated at constant velocity in inverse depth from the
            frame before (where both are valid), not the last depth itself.
        downsample: k: the band runs on the capture binned by k x k and its estimate is interpolated back to full
            resolution (>= 1; 1: the model's full-resolution band; see the module docstring). None (default): 2 for
            a pyramid (the resolution of its binned level: a fraction of the full-resolution band's work at
            about its accuracy; ``benchmarks/video_speed.py``'s ``temporal k=1`` rows run the other), 1 for a
            one-level model (smaller sensors, where the binned frame costs accuracy).

    Example:
        >>> TemporalOptions(band=2).to_dict()["band"]
        2
    """

    band: int = 1
    band_edges: BandEdges = "clamp"
    reach: int = 4
    min_prior_confidence: float = 0.5
    keyframe_interval: int = 60
    cut_threshold: float = 0.05
    max_invalid_growth: float = 0.02
    min_valid_ratio: float = 0.95
    extrapolate: bool = True
    downsample: int | None = None

    def __post_init__(self) -> None:
        check_option(self.band_edges, TEMPORAL_BAND_EDGES, "band_edges")
        if not isinstance(self.extrapolate, bool):
            raise OptionError(f"extrapolate must be a bool, got {self.extrapolate!r}")
        for name, least in (("band", 1), ("reach", 0), ("keyframe_interval", 1), ("downsample", 1)):
            check_int(getattr(self, name), name, least, none=name == "downsample")
        check_number(self.cut_threshold, "cut_threshold", 0.0, float("inf"), "a number in [0, inf] (inf: never a cut)",
                     infinite=True)
        for name in ("max_invalid_growth", "min_valid_ratio", "min_prior_confidence"):
            check_number(getattr(self, name), name, 0.0, 1.0, "a number in [0, 1]")

    def to_dict(self) -> dict[str, Any]:
        """The options as a JSON-ready dict."""
        return dataclasses.asdict(self)


class BandPrior(NamedTuple):
    """A prior at the temporal band's resolution (the binned frame's with ``downsample`` k > 1, else the reference
    half's): what :meth:`TemporalDepth.track` places its band by, and what it returns for the next frame.

    Attributes:
        inverse: (B, 1, h, w) inverse depth 1/Z (1/mm), within the depth range's bounds (any such value where not
            placed).
        placed: (B, 1, h, w) bool: the pixels whose prior places the band (valid and confident enough).

    Tensors, or numpy arrays where the temporal graph runs without torch.
    """

    inverse: Any
    placed: Any


class TrackedDepth(NamedTuple):
    """A frame's depth found around a prior, and the prior it leaves for the next frame.

    Attributes:
        result: the frame's :class:`~prismstereo.depth.result.DepthResult`, (B, *, H, W_ref) tensors (an ONNX
            temporal graph's: :class:`~prismstereo.export.OnnxDepthResult`).
        prior: the :class:`BandPrior` of this frame's band, (B, 1, h, w) each.
    """

    result: Any
    prior: BandPrior


def band_prior(depth: Any, valid: Any, confidence: Any, *,
               z_range: tuple[float, float], min_confidence: float, downsample: int = 1,
               size: tuple[int, int] | None = None) -> BandPrior:
    """A full-resolution result (B, 1, H, W_ref) as the temporal band's prior (B, 1, h, w): the pixels valid and at
    least ``min_confidence`` confident are placed; their inverse depth clipped to the range's bounds; with
    ``downsample`` k > 1 binned by k x k to ``size`` (h, w): each block's mean over its placed pixels (1/Z, so the
    mean of the sweep coordinate, affine in it), placed where at least half of them are.

    Torch tensors are binned by average pooling (the temporal graph's own computation); numpy arrays by block sums
    in numpy (:func:`_band_prior_numpy`: the same prior to float rounding, without torch).

    Args:
        depth: (B, 1, H, W_ref) depth (mm), anything (NaN too) where not valid.
        valid: (B, 1, H, W_ref) bool.
        confidence: (B, 1, H, W_ref) in [0, 1].
        z_range: (z_min, z_max) mm, the band's range.
        min_confidence: pixels less confident than this are not placed, in [0, 1].
        downsample: k >= 1.
        size: (h, w) the binned level's reference half; None: (H, W_ref) // k.

    Returns:
        BandPrior((B, 1, h, w) inverse depth, (B, 1, h, w) bool placed).

    Raises:
        ShapeError: tensors of different shapes, or a non-bool ``valid``.

    Example:
        >>> depth = torch.full((1, 1, 4, 4), 500.0); valid = torch.ones(1, 1, 4, 4, dtype=torch.bool)
        >>> prior = band_prior(depth, valid, torch.ones(1, 1, 4, 4), z_range=(400.0, 700.0), min_confidence=0.5,
        ...                    downsample=2)
        >>> prior.inverse.shape, round(1 / prior.inverse[0, 0, 0, 0].item(), 3), prior.placed.all().item()
        (torch.Size([1, 1, 2, 2]), 500.0, True)
    """
    numpy = isinstance(depth, np.ndarray)
    if numpy and (depth.ndim != 4 or depth.shape[1] != 1):
        raise ShapeError(f"depth must have shape (B, 1, H, W), got {tuple(depth.shape)}")
    if not numpy:
        check_shape(depth, ["B", 1, "H", "W"], "depth")
    for name, t in (("valid", valid), ("confidence", confidence)):
        if tuple(t.shape) != tuple(depth.shape):
            raise ShapeError(f"{name} must have depth's shape {tuple(depth.shape)}, got {tuple(t.shape)}")
    if str(valid.dtype) not in ("bool", "torch.bool"):
        raise ShapeError(f"valid must be bool, got {valid.dtype}")
    check_int(downsample, "downsample", 1)
    full = (int(depth.shape[-2]), int(depth.shape[-1]))
    h, w = size if size is not None else (full[0] // downsample, full[1] // downsample)
    if numpy:
        return _band_prior_numpy(depth, valid, confidence, z_range, min_confidence, downsample, (h, w))
    import torch

    placed = valid & (confidence >= min_confidence)
    z = torch.tensor(z_range, dtype=depth.dtype, device=depth.device)
    bounds = 1.0 / z
    inverse = (1.0 / torch.where(placed, depth, z[0])).clamp(bounds[1], bounds[0])  # finite everywhere
    if downsample == 1:
        return BandPrior(inverse, placed)
    return BandPrior(*_binned_prior(inverse, placed, downsample, h, w, full))


def _band_prior_numpy(depth: np.ndarray, valid: np.ndarray, confidence: np.ndarray, z_range: tuple[float, float],
                      min_confidence: float, k: int, size: tuple[int, int]) -> BandPrior:
    """:func:`band_prior` of numpy arrays, in numpy: the same rule, each k x k block's sums (a last block cut by the
    edge: its pixels alone, as average pooling with ``ceil_mode`` divides)."""
    placed = valid & (confidence >= min_confidence)
    z = np.asarray(z_range, dtype=depth.dtype)
    bounds = np.asarray(1.0, dtype=depth.dtype) / z
    inverse = np.clip(np.asarray(1.0, dtype=depth.dtype) / np.where(placed, depth, z[0]), bounds[1], bounds[0])
    if k == 1:
        return BandPrior(inverse, placed)
    h, w = size
    b, _, height, width = depth.shape
    rows, cols = -(-height // k), -(-width // k)

    def block_sums(x: np.ndarray) -> np.ndarray:
        padded = np.zeros((b, 1, rows * k, cols * k), dtype=x.dtype)
        padded[..., :height, :width] = x
        return padded.reshape(b, 1, rows, k, cols, k).sum(axis=(3, 5))[..., :h, :w]

    weight = placed.astype(depth.dtype)
    counts = block_sums(np.ones((1, 1, height, width), dtype=depth.dtype))[:1]
    share = block_sums(weight) / counts
    mean = (block_sums(inverse * weight) / counts) / np.maximum(share, np.asarray(1e-6, dtype=depth.dtype))
    return BandPrior(mean, share >= 0.5)


def _binned_prior(x: torch.Tensor, placed: torch.Tensor, k: int, h: int, w: int,
                  full: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, 1, H, W_ref) values (inverse depths) and usable-prior mask binned by k x k to the binned level's
    (B, 1, h, w): the mean over each block's usable pixels (0 in a block without any), usable where at least half of
    them are. ``full``: (H, W_ref) as ints (static in an exported graph)."""
    import torch.nn.functional as F

    from prismstereo.runtime import crop

    weight = placed.to(x.dtype)
    # ceil_mode: a reference half whose width k does not divide (512 / 3) has a last binned column of fewer pixels
    # (only then: onnxruntime's pooling with ceil_mode is slower, where it changes nothing)
    ceil = bool(full[0] % k or full[1] % k)
    share = crop(F.avg_pool2d(weight, k, ceil_mode=ceil), h, w)
    mean = crop(F.avg_pool2d(x * weight, k, ceil_mode=ceil), h, w) / share.clamp_min(1e-6)
    return mean, share >= 0.5
