"""Depth of a stream of frames, for applications: one :class:`~prismstereo.predictor.Predictor` (a model in torch or
its exported graphs in onnxruntime), frames pushed one at a time from any thread, per-frame timing.

Frames are processed in the order they are pushed; a lock serialises concurrent pushes (a capture thread and a UI
thread may both call :meth:`DepthStream.push`). Frames may be (C, H, W) / (1, C, H, W) tensors in [0, 1] or
OpenCV's decoded uint8 (H, W) / (H, W, 3) BGR arrays; colour is converted to grey
(:func:`~prismstereo.conventions.to_grey`) when the model takes one channel.

With ``temporal`` the stream uses the temporal prior (:mod:`prismstereo.classical.temporal`): a key frame gets the
full model, the frames after it a narrow band around the previous frame's depth (extrapolated at constant velocity
in inverse depth when ``extrapolate``), kept at the band's resolution (:class:`~prismstereo.classical.BandPrior`).
A frame is a key frame when it is the first, when ``keyframe_interval`` frames passed since the last, on a scene cut
(its 8 x 8 block means differ from the previous frame's by more than ``cut_threshold`` on average), when the prior's
invalid share grew by more than ``max_invalid_growth`` since the last key frame, and (computed again) when the
tracked result's valid share fell below ``min_valid_ratio`` times the key frame's. The temporal prior is off by
default in the API (pushed frames need not be a video), on by default for videos in ``prismstereo depth``.

An ONNX stream does its own tensor work (the frame's conversion, the cut test's block means, the extrapolated
prior, the valid shares, a key frame's prior: a few passes over one plane) on
:func:`~prismstereo.threads.thread_plan`'s ``side`` threads (one): between the graph's runs torch's OpenMP workers
and onnxruntime's spinning intra-op threads otherwise compete for the same cores, and each waits for the other.
"""

from __future__ import annotations

import contextlib
import dataclasses
import threading
import time
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from prismstereo.classical.prior import BandPrior, TemporalOptions
from prismstereo.conventions import to_grey
from prismstereo.errors import OptionError, ShapeError
from prismstereo.models import DepthModel
from prismstereo.predictor import Predictor
from prismstereo.stream.video import frame_to_grey, frame_to_tensor
from prismstereo.threads import thread_plan, torch_threads

__all__ = ["StreamResult", "DepthStream"]

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
    """

    depth: torch.Tensor
    valid: torch.Tensor
    confidence: torch.Tensor
    frame: int
    milliseconds: float
    keyframe: bool = True


def _block_means(image: torch.Tensor) -> torch.Tensor:
    """The 8 x 8 block means of a (1, 1, H, W) grey image, the cut test's thumbnail (the image itself when smaller
    than a block): OpenCV's area resize of the whole blocks on the CPU (the same means as torch's average pooling to
    float rounding, from a faster kernel on one thread), torch's pooling elsewhere."""
    h, w = image.shape[-2:]
    if min(h, w) < 8:
        return image
    if image.device.type != "cpu" or image.dtype not in (torch.float32, torch.float64) or image.shape[:2] != (1, 1):
        return F.avg_pool2d(image, 8)
    blocks = np.ascontiguousarray(image[0, 0, :h // 8 * 8, :w // 8 * 8].numpy())
    return torch.from_numpy(cv2.resize(blocks, (w // 8, h // 8), interpolation=cv2.INTER_AREA))[None, None]


def _predictor(model: Predictor | DepthModel | str | Path, temporal: bool | TemporalOptions) -> Predictor:
    """The stream's predictor of ``model`` (the class docstring)."""
    if isinstance(model, Predictor):
        return model
    from prismstereo.export import OnnxDepth

    if isinstance(model, OnnxDepth):
        return Predictor.from_graphs(model)
    if isinstance(model, (str, Path)):
        if Path(model).suffix.lower() != ".onnx":
            raise OptionError(f"a stream's model must be a predictor, a depth model or an .onnx file, got {model}")
        return Predictor.from_graphs(model)
    if not isinstance(model, DepthModel):
        raise OptionError(f"a stream's model must be a predictor, a depth model or an .onnx file, got "
                          f"{type(model).__name__}")
    options = None if temporal is False else temporal if isinstance(temporal, TemporalOptions) else TemporalOptions()
    return Predictor(model, temporal=options)


def _share(valid: torch.Tensor) -> float:
    """The share of True in a bool mask (numpy counts it in place, without a float copy of the mask)."""
    return np.count_nonzero(valid.numpy(force=True)) / max(valid.numel(), 1)


class DepthStream:
    """Depth frame after frame from one :class:`~prismstereo.predictor.Predictor` (a model in torch, or its graphs
    in onnxruntime).

    Args:
        model: a :class:`~prismstereo.predictor.Predictor`, a depth model (:class:`~prismstereo.models.DepthModel`,
            run in torch) or an exported per-frame graph (an ``.onnx`` path or an
            :class:`~prismstereo.export.OnnxDepth`; :meth:`~prismstereo.predictor.Predictor.from_graphs` with a
            temporal graph for the temporal prior).
        temporal: False (default: every frame on its own), True (the temporal prior: a model's band with default
            :class:`~prismstereo.classical.TemporalOptions`, a predictor's band with its options) or the options (a
            model's band with them; with a predictor, the key-frame rules (:data:`KEYFRAME_RULES`): its band keeps
            its own options).

    Attributes:
        predictor: the :class:`~prismstereo.predictor.Predictor`.
        backend: its backend, 'torch' or 'onnx'.
        channels, height, width: the frames the stream takes (a grey model: 1 channel, colour converted).
        temporal: the temporal prior's options, None without it.
        frames: frames processed so far.
        keyframes: frames computed by the full model so far.
        times_ms: per-frame computation times (ms), in order.

    Raises:
        OptionError: a model that is neither a predictor, a depth model nor an ``.onnx`` path; the temporal prior
            asked of a model or predictor without a band.

    Example:
        >>> from prismstereo.models import build_model
        >>> stream = DepthStream(build_model(thesis_setup1().downscaled(16), z_range=(400.0, 700.0)))
        >>> out = stream.push(torch.rand(3, 48, 64))
        >>> out.depth.shape, out.frame, stream.frames
        (torch.Size([1, 1, 48, 32]), 0, 1)
    """

    def __init__(self, model: Predictor | DepthModel | str | Path, *,
                 temporal: bool | TemporalOptions = False) -> None:
        self._lock = threading.Lock()
        self.frames = self.keyframes = 0
        self.times_ms: list[float] = []
        if not isinstance(temporal, (bool, TemporalOptions)):
            raise OptionError(f"temporal must be a bool or TemporalOptions, got {type(temporal).__name__}")
        self.predictor = predictor = _predictor(model, temporal)
        if temporal is not False and predictor.temporal is None:
            raise OptionError(f"the temporal prior needs a band to place on the previous frame: {predictor.summary} "
                              "has none (a classical model with a full-resolution band, or a predictor built with "
                              "temporal options)")
        self.backend = predictor.backend
        self.channels = predictor.channels or 1
        self.height, self.width = predictor.rig.image_height, predictor.rig.image_width
        self.temporal: TemporalOptions | None = None
        if temporal is not False:  # the band's options are the predictor's; given options set the key-frame rules
            given = isinstance(temporal, TemporalOptions)
            rules = {k: getattr(temporal, k) for k in KEYFRAME_RULES} if given else {}
            self.temporal = dataclasses.replace(predictor.temporal, **rules)
        self._prior: BandPrior | None = None  # the last frame's, at the band's resolution
        self._before: BandPrior | None = None  # the frame before's (extrapolation)
        self._thumb: torch.Tensor | None = None
        self._since_key = 0
        self._key_valid = self._last_valid = 1.0  # valid shares of the last key frame and of the last frame

    def _prepare(self, frame: torch.Tensor | np.ndarray) -> torch.Tensor:
        if isinstance(frame, np.ndarray):  # OpenCV's decoded frame: uint8 (H, W) or (H, W, 3) BGR
            frame = frame_to_grey(frame) if self.channels == 1 else frame_to_tensor(frame)
        if not isinstance(frame, torch.Tensor) or frame.dim() not in (3, 4) or (frame.dim() == 4 and
                                                                                 frame.shape[0] != 1):
            got = tuple(frame.shape) if isinstance(frame, torch.Tensor) else type(frame).__name__
            raise ShapeError(f"a frame must be (C, H, W) or (1, C, H, W), got {got}")
        image = frame if frame.dim() == 4 else frame[None]
        if tuple(image.shape[-2:]) != (self.height, self.width):
            raise ShapeError(f"frame is {image.shape[-1]}x{image.shape[-2]} px but the model expects "
                             f"{self.width}x{self.height}")
        if not torch.is_floating_point(image):
            image = image.float() / 255.0
        if image.shape[1] != self.channels:
            if self.channels != 1 or image.shape[1] != 3:
                raise ShapeError(f"frame has {image.shape[1]} channels, the model takes {self.channels}")
            image = to_grey(image)
        return image

    def push(self, frame: torch.Tensor | np.ndarray) -> StreamResult:
        """The depth of the next frame (thread-safe: concurrent pushes run one after the other).

        Args:
            frame: (C, H, W) or (1, C, H, W) float in [0, 1], or a uint8 (H, W) / (H, W, 3) BGR array.

        Returns:
            StreamResult(depth, valid, confidence (1, 1, H, W_ref) each, frame, milliseconds).

        Raises:
            ShapeError: a frame of the wrong size, channels or type.
        """
        # an ONNX stream's own tensor work on one torch thread (the module docstring); a torch model keeps them all
        side = thread_plan().side
        with torch_threads(side) if self.backend == "onnx" else contextlib.nullcontext():
            return self._push(frame)

    def _push(self, frame: torch.Tensor | np.ndarray) -> StreamResult:
        image = self._prepare(frame)
        with self._lock:
            t0 = time.perf_counter()
            thumb = None
            if self.temporal is not None:
                thumb = _block_means(to_grey(image))
            key = self._keyframe(thumb)
            res, prior = (self._run(image), None) if key else self._track(image, self._predicted())
            share = None if self.temporal is None else _share(res.valid)
            if not key and share < self.temporal.min_valid_ratio * self._key_valid:
                key, res, prior = True, self._run(image), None  # the tracking lost too much: the full model after all
                share = _share(res.valid)
            if self.temporal is not None and prior is None:  # a key frame's result as the band's prior
                prior = self._band_prior(res)
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

    def _run(self, image: torch.Tensor):
        """The model on one image."""
        return self.predictor.depth(image)

    def _track(self, image: torch.Tensor, prior: BandPrior):
        """The temporal band on one image: (its result, the next frame's prior)."""
        return self.predictor.track(image, prior)

    def _band_prior(self, res) -> BandPrior:
        """A key frame's result as the band's prior."""
        return self.predictor.band_prior(res)

    def _keyframe(self, thumb: torch.Tensor | None) -> bool:
        """Whether the next frame (its 8 x 8 block means ``thumb``) gets the full model (the class docstring)."""
        options, prior = self.temporal, self._prior
        if options is None or prior is None or self._thumb is None or self._since_key + 1 >= options.keyframe_interval:
            return True
        if float((thumb - self._thumb).abs().mean()) > options.cut_threshold:
            return True
        return (1.0 - self._last_valid) - (1.0 - self._key_valid) > options.max_invalid_growth

    def _predicted(self) -> BandPrior:
        """The prior of the next frame: the last one, its inverse depth extrapolated at constant velocity from the
        frame before where both are placed (``extrapolate``; the band clips it to the range)."""
        prior, before = self._prior, self._before
        if not self.temporal.extrapolate or before is None:
            return prior
        inverse = torch.where(prior.placed & before.placed, 2.0 * prior.inverse - before.inverse, prior.inverse)
        return BandPrior(inverse, prior.placed)

    def frames_per_second(self) -> float:
        """Frames per second of the depth computation over the frames so far (0 before any frame).

        Example:
            >>> from prismstereo.classical.model import PrismStereo
            >>> stream = DepthStream(PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0)))
            >>> before = stream.frames_per_second(); _ = stream.push(torch.rand(1, 48, 64))
            >>> before, stream.frames_per_second() > 0
            (0.0, True)
        """
        total = sum(self.times_ms)
        return len(self.times_ms) / (total / 1000.0) if total > 0 else 0.0
