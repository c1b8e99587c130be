"""Depth of a stream of frames, without torch: :class:`FrameStream`, the key-frame rules of the temporal prior around
any predictor, on numpy frames. :class:`~prismstereo.stream.DepthStream` is the same stream for tensors (a model in
torch, or its graphs); a process that only runs exported graphs (:class:`~prismstereo.export.graphs.GraphPredictor`)
runs this one and never imports torch.

Frames are processed in the order they are pushed; a lock serialises concurrent pushes (a capture thread and a UI
thread may both call :meth:`FrameStream.push`).

With ``temporal`` the stream uses the temporal prior (:mod:`prismstereo.classical.temporal`): a key frame gets the
full model, the frames after it a narrow band around the previous frame's depth (extrapolated at constant velocity
in inverse depth when ``extrapolate``), kept at the band's resolution (:class:`~prismstereo.classical.BandPrior`).
A frame is a key frame when it is the first, when ``keyframe_interval`` frames passed since the last, on a scene cut
(its 8 x 8 block means differ from the previous frame's by more than ``cut_threshold`` on average), when the prior's
invalid share grew by more than ``max_invalid_growth`` since the last key frame, and (computed again) when the
tracked result's valid share fell below ``min_valid_ratio`` times the key frame's. The temporal prior is off by
default in the API (pushed frames need not be a video), on by default for videos in ``prismstereo depth``.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from typing import Any, NamedTuple

import cv2
import numpy as np

from prismstereo.classical.prior import BandPrior, TemporalOptions
from prismstereo.errors import OptionError, ShapeError
from prismstereo.export.session import as_array
from prismstereo.io import grey_array
from prismstereo.sources import bgr_to_grey, bgr_to_rgb

__all__ = ["KEYFRAME_RULES", "FrameStream", "StreamResult", "block_means"]

# the options of the temporal prior that are the stream's (the others are its band's)
KEYFRAME_RULES = ("keyframe_interval", "cut_threshold", "max_invalid_growth", "min_valid_ratio", "extrapolate")


class StreamResult(NamedTuple):
    """One pushed frame's depth.

    Attributes:
        depth: (1, 1, H, W_ref) depth Z (mm); meaningless where not valid.
        valid: (1, 1, H, W_ref) bool.
        confidence: (1, 1, H, W_ref) in [0, 1].
        frame: 0-based number of the frame in the stream.
        milliseconds: time of the depth computation (the model or graph alone; a key frame computed again after
            a failed tracking step: both).
        keyframe: computed by the full model (always, without the temporal prior), not around a prior.

    Tensors from :class:`~prismstereo.stream.DepthStream`, numpy arrays from a :class:`FrameStream` of graphs.
    """

    depth: Any
    valid: Any
    confidence: Any
    frame: int
    milliseconds: float
    keyframe: bool = True


def block_means(grey: np.ndarray) -> np.ndarray:
    """The 8 x 8 block means of an (H, W) float grey image (OpenCV's area resize of the whole blocks), the cut test's
    thumbnail; the image itself when smaller than a block.

    Example:
        >>> block_means(np.ones((16, 24), np.float32)).shape
        (2, 3)
    """
    h, w = grey.shape[-2:]
    if min(h, w) < 8:
        return grey
    blocks = np.ascontiguousarray(grey[:h // 8 * 8, :w // 8 * 8])
    return cv2.resize(blocks, (w // 8, h // 8), interpolation=cv2.INTER_AREA)


def _share(valid: Any) -> float:
    """The share of True in a bool mask (numpy counts it in place, without a float copy of the mask)."""
    array = as_array(valid)
    return np.count_nonzero(array) / max(array.size, 1)


class FrameStream:
    """Depth frame after frame from a predictor (the key-frame rules of the module docstring), on numpy frames.

    Args:
        predictor: what computes the depth: :meth:`depth` of a (1, C, H, W) batch and, for the temporal prior,
            ``track``, ``band_prior`` and ``temporal`` (a :class:`~prismstereo.export.graphs.GraphPredictor`, or a
            :class:`~prismstereo.predictor.Predictor`).
        temporal: False (default: every frame on its own), True (the temporal prior with the predictor's band
            options) or options whose key-frame rules (:data:`KEYFRAME_RULES`) replace the predictor's.

    Attributes:
        predictor, backend ('torch' or 'onnx'), channels, height, width (the frames the stream takes: a grey model
        takes 1 channel, colour converted), temporal (the prior's options, None without it), frames, keyframes,
        times_ms (per-frame computation times, ms, in order).

    Raises:
        OptionError: the temporal prior asked of a predictor without a band; bad ``temporal``.

    Example:
        >>> from prismstereo.export.graphs import GraphPredictor
        >>> stream = FrameStream(GraphPredictor("depth.onnx"))  # doctest: +SKIP
        >>> stream.push(np.zeros((768, 1024), np.uint8)).depth.shape  # doctest: +SKIP
        (1, 1, 768, 512)
    """

    def __init__(self, predictor: Any, *, temporal: bool | TemporalOptions = False) -> None:
        self._lock = threading.Lock()
        self.frames = self.keyframes = 0
        self.times_ms: list[float] = []
        if not isinstance(temporal, (bool, TemporalOptions)):
            raise OptionError(f"temporal must be a bool or TemporalOptions, got {type(temporal).__name__}")
        self.predictor = predictor
        if temporal is not False and predictor.temporal is None:
            raise OptionError(f"the temporal prior needs a band to place on the previous frame: {predictor.summary} "
                              "has none (a classical model with a full-resolution band, or a predictor built with "
                              "temporal options)")
        self.backend = predictor.backend
        self.channels = predictor.channels or 1
        self.height, self.width = predictor.image_size
        self.temporal: TemporalOptions | None = None
        if temporal is not False:  # the band's options are the predictor's; given options set the key-frame rules
            given = isinstance(temporal, TemporalOptions)
            rules = {k: getattr(temporal, k) for k in KEYFRAME_RULES} if given else {}
            self.temporal = dataclasses.replace(predictor.temporal, **rules)
        self._prior: BandPrior | None = None  # the last frame's, at the band's resolution
        self._before: BandPrior | None = None  # the frame before's (extrapolation)
        self._thumb: np.ndarray | None = None
        self._since_key = 0
        self._key_valid = self._last_valid = 1.0  # valid shares of the last key frame and of the last frame

    def _check_size(self, shape: tuple[int, ...]) -> None:
        if tuple(shape[-2:]) != (self.height, self.width):
            raise ShapeError(f"frame is {shape[-1]}x{shape[-2]} px but the model expects {self.width}x{self.height}")

    def _prepare(self, frame: Any) -> Any:
        """The model's (1, C, H, W) float input of a pushed frame."""
        if not isinstance(frame, np.ndarray):
            raise ShapeError(f"a frame must be a numpy array, got {type(frame).__name__}")
        if frame.dtype == np.uint8 and frame.ndim in (2, 3) and (frame.ndim == 2 or frame.shape[2] == 3):
            frame = bgr_to_grey(frame) if self.channels == 1 else bgr_to_rgb(frame)  # OpenCV's decoded frame
        if frame.ndim not in (3, 4) or (frame.ndim == 4 and frame.shape[0] != 1) or not np.issubdtype(
                frame.dtype, np.floating):
            raise ShapeError(f"a frame must be a (C, H, W) or (1, C, H, W) float array in [0, 1] or OpenCV's uint8 "
                             f"(H, W) / (H, W, 3) BGR, got {frame.dtype} {frame.shape}")
        image = np.asarray(frame if frame.ndim == 4 else frame[None], dtype=np.float32)
        self._check_size(image.shape)
        return self._model_channels(image, grey_array)

    def _model_channels(self, image: Any, grey: Any) -> Any:
        """A (1, C, H, W) frame with the model's channels: a colour frame ``grey`` (image) for a grey model."""
        if image.shape[1] != self.channels:
            if self.channels != 1 or image.shape[1] != 3:
                raise ShapeError(f"frame has {image.shape[1]} channels, the model takes {self.channels}")
            image = grey(image)
        return image

    def _thumbnail(self, image: Any) -> np.ndarray:
        """The cut test's 8 x 8 block means of a prepared (1, C, H, W) frame."""
        return block_means(grey_array(np.asarray(image, dtype=np.float32))[0, 0])

    def push(self, frame: Any) -> StreamResult:
        """The depth of the next frame (thread-safe: concurrent pushes run one after the other).

        Args:
            frame: (C, H, W) or (1, C, H, W) float in [0, 1], or a uint8 (H, W) / (H, W, 3) BGR array.

        Returns:
            StreamResult(depth, valid, confidence (1, 1, H, W_ref) each, frame, milliseconds, keyframe).

        Raises:
            ShapeError: a frame of the wrong size, channels or type.
        """
        image = self._prepare(frame)
        with self._lock:
            t0 = time.perf_counter()
            thumb = None if self.temporal is None else self._thumbnail(image)
            key = self._keyframe(thumb)
            res, prior = (self.predictor.depth(image), None) if key else self.predictor.track(image, self._predicted())
            share = None if self.temporal is None else _share(res.valid)
            if not key and share < self.temporal.min_valid_ratio * self._key_valid:
                # the tracking lost too much: the full model after all
                key, res, prior = True, self.predictor.depth(image), None
                share = _share(res.valid)
            if self.temporal is not None and prior is None:  # a key frame's result as the band's prior
                prior = self.predictor.band_prior(res)
            ms = 1000.0 * (time.perf_counter() - t0)
            number = self.frames
            self.frames += 1
            self.keyframes += key
            self.times_ms.append(ms)
            if self.temporal is not None:
                self._thumb, self._before, self._prior, self._last_valid = thumb, self._prior, prior, share
                self._since_key = 0 if key else self._since_key + 1
                if key:
                    self._key_valid = share
        return StreamResult(res.depth, res.valid, res.confidence, number, ms, key)

    def reset(self) -> None:
        """Forget the previous frames (the next one is a key frame, as after a cut); counts and times stay."""
        with self._lock:
            self._prior = self._before = self._thumb = None
            self._since_key, self._key_valid, self._last_valid = 0, 1.0, 1.0

    def _keyframe(self, thumb: np.ndarray | None) -> bool:
        """Whether the next frame (its 8 x 8 block means ``thumb``) gets the full model (the module docstring)."""
        options, prior = self.temporal, self._prior
        if options is None or prior is None or self._thumb is None or self._since_key + 1 >= options.keyframe_interval:
            return True
        if float(np.abs(thumb - self._thumb).mean()) > options.cut_threshold:
            return True
        return (1.0 - self._last_valid) - (1.0 - self._key_valid) > options.max_invalid_growth

    def _predicted(self) -> BandPrior:
        """The prior of the next frame: the last one, its inverse depth extrapolated at constant velocity from the
        frame before where both are placed (``extrapolate``; the band clips it to the range)."""
        prior, before = self._prior, self._before
        if not self.temporal.extrapolate or before is None:
            return prior
        both = prior.placed & before.placed
        ahead = 2.0 * prior.inverse - before.inverse
        if isinstance(ahead, np.ndarray):
            return BandPrior(np.where(both, ahead, prior.inverse), prior.placed)
        return BandPrior(ahead.where(both, prior.inverse), prior.placed)  # a tensor's where: torch.where(both, ...)

    def frames_per_second(self) -> float:
        """Frames per second of the depth computation over the frames so far (0 before any frame).

        Example:
            >>> stream.frames_per_second()  # doctest: +SKIP
            21.4
        """
        total = sum(self.times_ms)
        return len(self.times_ms) / (total / 1000.0) if total > 0 else 0.0
