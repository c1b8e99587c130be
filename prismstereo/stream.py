"""Depth of a stream of frames, for applications: one model (torch or its exported ONNX graph), frames pushed one
at a time from any thread, per-frame timing.

:class:`DepthStream` wraps a :class:`~prismstereo.model.PrismStereo` (or any module returning a
:class:`~prismstereo.model.DepthResult`) or an ONNX file written by :func:`~prismstereo.export.export_onnx`
(run by :class:`~prismstereo.export.OnnxDepth`). Frames are processed in the order they are pushed; a lock
serialises concurrent pushes (a capture thread and a UI thread may both call :meth:`DepthStream.push`).
Frames may be (C, H, W) / (1, C, H, W) tensors in [0, 1] or OpenCV's decoded uint8 (H, W) / (H, W, 3) BGR arrays;
colour is converted to grey when the model takes one channel.

With ``temporal`` the stream uses the temporal prior (:mod:`prismstereo.depth.temporal`): a key frame gets the full
model, the frames after it a narrow band around the previous frame's depth (extrapolated at constant velocity in
inverse depth when ``extrapolate``), kept at the band's resolution
(:class:`~prismstereo.depth.temporal.BandPrior`). A frame is a key frame when it is the first, when
``keyframe_interval`` frames passed since the last, on a scene cut (its 8 x 8 block means differ from the previous
frame's by more than ``cut_threshold`` on average), when the prior's invalid share grew by more than
``max_invalid_growth`` since the last key frame, and (computed again) when the tracked result's valid share fell
below ``min_valid_ratio`` times the key frame's. The temporal prior is off by default in the API (pushed frames
need not be a video; an ONNX stream needs the second graph), on by default for videos in ``prismstereo depth``.

An ONNX stream does its own tensor work (the frame's conversion, the cut test's block means, the extrapolated
prior, the valid shares, a key frame's prior: a few passes over one plane) on one torch thread
(:func:`~prismstereo.threads.torch_threads`): between the graph's runs torch's OpenMP workers and onnxruntime's
spinning intra-op threads otherwise compete for the same cores, and each waits for the other.
"""

from __future__ import annotations

import contextlib
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.depth.temporal import BandPrior, TemporalDepth, TemporalOptions
from prismstereo.errors import OptionError, ShapeError
from prismstereo.io import to_grey
from prismstereo.matching.cost import grey
from prismstereo.threads import session_threads, torch_threads
from prismstereo.video import frame_to_grey, frame_to_tensor

if TYPE_CHECKING:
    from prismstereo.export import OnnxDepth

__all__ = ["StreamResult", "DepthStream"]

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


def _share(valid: torch.Tensor) -> float:
    """The share of True in a bool mask (numpy counts it in place, without a float copy of the mask)."""
    return np.count_nonzero(valid.numpy(force=True)) / max(valid.numel(), 1)


class DepthStream:
    """Depth frame after frame from one model.

    Args:
        model: a torch module returning a :class:`~prismstereo.model.DepthResult` for (1, C, H, W) images, the
            path of an exported ONNX graph (``.onnx``) or an :class:`~prismstereo.export.OnnxDepth` session.
        temporal: False (default: every frame on its own), True (the temporal prior with default
            :class:`~prismstereo.depth.temporal.TemporalOptions`, or a temporal graph's options) or the options.
            A torch model needs a full-resolution band (:func:`~prismstereo.depth.temporal.supports_temporal`).
        temporal_graph: ONNX streams with the temporal prior: a temporal graph
            (:func:`~prismstereo.export.export_onnx` with ``temporal=``; a path or an ``OnnxDepth``) of the same
            sensor, from ``model`` or from the classical model that tracks for it (see ``tracker``); implies
            ``temporal`` (its options, unless ``temporal`` gives others for the key-frame rules).
        tracker: torch streams with the temporal prior: the :class:`~prismstereo.model.PrismStereo` whose band
            tracks between key frames (default ``model`` itself). Key frames by a model without a band, such as
            :class:`~prismstereo.learned.HybridStereo`, tracked by the classical band: the key frames cost what
            that model costs.
        threads: onnxruntime intra-op threads (ONNX graphs opened from a path; a temporal graph's: one,
            :func:`~prismstereo.threads.session_threads`).
        spinning: onnxruntime thread spinning (ONNX graphs only; see :class:`~prismstereo.export.OnnxDepth`).

    Attributes:
        backend: 'torch' or 'onnx'.
        channels, height, width: the input the model expects (torch: from its rig; ONNX: from its metadata).
        temporal: the temporal prior's options, None without it.
        frames: frames processed so far.
        keyframes: frames computed by the full model so far.
        times_ms: per-frame computation times (ms), in order.

    Raises:
        OptionError: a model that is neither a module with a rig nor an ``.onnx`` path; a temporal prior the model
            cannot use or an ONNX stream with the temporal prior but without its temporal graph.

    Example:
        >>> from prismstereo.model import PrismStereo
        >>> stream = DepthStream(PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0)))
        >>> out = stream.push(torch.rand(3, 48, 64))
        >>> out.depth.shape, out.frame, stream.frames
        (torch.Size([1, 1, 48, 32]), 0, 1)
    """

    def __init__(self, model: nn.Module | str | Path | OnnxDepth, *, temporal: bool | TemporalOptions = False,
                 temporal_graph: str | Path | OnnxDepth | None = None, tracker: nn.Module | None = None,
                 threads: int = 2, spinning: bool = True) -> None:
        self._lock = threading.Lock()
        self.frames = self.keyframes = 0
        self.times_ms: list[float] = []
        from prismstereo.export import OnnxDepth

        if not isinstance(temporal, (bool, TemporalOptions)):
            raise OptionError(f"temporal must be a bool or TemporalOptions, got {type(temporal).__name__}")

        if isinstance(model, (str, Path, OnnxDepth)):
            if not isinstance(model, OnnxDepth) and Path(model).suffix.lower() != ".onnx":
                raise OptionError(f"a stream's model must be a torch module or an .onnx file, got {model}")
            self._runner = model if isinstance(model, OnnxDepth) else OnnxDepth(model, threads=threads,
                                                                                spinning=spinning)
            self.backend = "onnx"
            self.channels, self.height, self.width = self._runner.input_shape
        elif isinstance(model, nn.Module) and hasattr(model, "rig"):
            self._runner = model.eval()
            self.backend = "torch"
            self.channels = 1
            self.height, self.width = model.rig.image_height, model.rig.image_width
        else:
            raise OptionError(f"a stream's model must be a torch module with a rig (e.g. PrismStereo) or an .onnx "
                              f"file, got {type(model).__name__}")
        self._tracker = None
        if self.backend == "torch" and temporal_graph is not None:
            raise OptionError("temporal_graph is the ONNX temporal graph: a torch stream builds its own")
        if tracker is not None and (self.backend != "torch" or temporal is False):
            raise OptionError("tracker is a torch stream's with the temporal prior (an ONNX stream takes its "
                              "temporal_graph)")
        rig = getattr(tracker, "rig", None)
        if tracker is not None and (rig is None or (rig.image_height, rig.image_width) != (self.height, self.width)):
            raise OptionError(f"the tracker must be a model of the stream's {self.width}x{self.height} sensor")
        if self.backend == "torch" and temporal is not False:
            self._tracker = TemporalDepth(tracker if tracker is not None else model,
                                          temporal if isinstance(temporal, TemporalOptions) else None).eval()
            self.temporal: TemporalOptions | None = self._tracker.options
        elif self.backend == "onnx" and (temporal is not False or temporal_graph is not None):
            if temporal_graph is None:
                raise OptionError("an ONNX stream with the temporal prior needs temporal_graph: the model's temporal "
                                  "graph (export_onnx(model, path, temporal=TemporalOptions()))")
            graph = temporal_graph if isinstance(temporal_graph, OnnxDepth) else OnnxDepth(
                temporal_graph, threads=session_threads(threads, temporal=True), spinning=spinning)
            if graph.temporal is None:
                raise OptionError(f"{graph.path.name} is a per-frame graph, not a temporal one")
            if graph.input_shape != self._runner.input_shape:
                raise OptionError(f"the temporal graph takes {graph.input_shape}, the model {self._runner.input_shape}")
            self._tracker = graph
            self.temporal = temporal if isinstance(temporal, TemporalOptions) else graph.temporal
        else:
            self.temporal = None
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
        with torch_threads(1) if self.backend == "onnx" else contextlib.nullcontext():
            return self._push(frame)

    def _push(self, frame: torch.Tensor | np.ndarray) -> StreamResult:
        image = self._prepare(frame)
        with self._lock:
            t0 = time.perf_counter()
            thumb = None
            if self.temporal is not None:
                thumb = _block_means(grey(image))
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

    def _inference(self):
        """torch's inference mode around a torch model's run (an ONNX graph's needs none)."""
        return torch.inference_mode() if self.backend == "torch" else contextlib.nullcontext()

    def _run(self, image: torch.Tensor):
        """The model on one image."""
        with self._inference():
            return self._runner(image)

    def _track(self, image: torch.Tensor, prior: BandPrior):
        """The temporal band on one image: (its result, the next frame's prior)."""
        with self._inference():
            return self._tracker.track(image, prior)

    def _band_prior(self, res) -> BandPrior:
        """A key frame's result as the band's prior."""
        with torch.inference_mode():
            return self._tracker.band_prior(res.depth, res.valid, res.confidence)

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
            >>> from prismstereo.model import PrismStereo
            >>> stream = DepthStream(PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0)))
            >>> before = stream.frames_per_second(); _ = stream.push(torch.rand(1, 48, 64))
            >>> before, stream.frames_per_second() > 0
            (0.0, True)
        """
        total = sum(self.times_ms)
        return len(self.times_ms) / (total / 1000.0) if total > 0 else 0.0
