"""Depth of a stream of frames, for applications: one :class:`~prismstereo.predictor.Predictor` (a model in torch or
its exported graphs in onnxruntime), frames pushed one at a time from any thread, per-frame timing.

:class:`DepthStream` is :class:`~prismstereo.stream.frame_stream.FrameStream` (the key-frame rules of the temporal
prior, its module docstring) for tensors: frames may be (C, H, W) / (1, C, H, W) tensors in [0, 1], float arrays,
or OpenCV's decoded uint8 (H, W) / (H, W, 3) BGR arrays; colour is converted to grey
(:func:`~prismstereo.conventions.to_grey`) when the model takes one channel.

An ONNX stream does its own tensor work (the frame's conversion, the cut test's block means, the extrapolated
prior, the valid shares, a key frame's prior: a few passes over one plane) on
:func:`~prismstereo.threads.thread_plan`'s ``side`` threads (one): between the graph's runs torch's OpenMP workers
and onnxruntime's spinning intra-op threads otherwise compete for the same cores, and each waits for the other.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from prismstereo.classical.prior import TemporalOptions
from prismstereo.conventions import to_grey
from prismstereo.errors import OptionError, ShapeError
from prismstereo.models import DepthModel
from prismstereo.predictor import Predictor
from prismstereo.stream.frame_stream import KEYFRAME_RULES, FrameStream, StreamResult, block_means
from prismstereo.stream.video import frame_to_grey, frame_to_tensor
from prismstereo.threads import thread_plan, torch_threads

__all__ = ["KEYFRAME_RULES", "DepthStream", "StreamResult"]


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


class DepthStream(FrameStream):
    """Depth frame after frame from one :class:`~prismstereo.predictor.Predictor` (a model in torch, or its graphs
    in onnxruntime), on tensors.

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
        if not isinstance(temporal, (bool, TemporalOptions)):
            raise OptionError(f"temporal must be a bool or TemporalOptions, got {type(temporal).__name__}")
        super().__init__(_predictor(model, temporal), temporal=temporal)

    def _prepare(self, frame: torch.Tensor | np.ndarray) -> torch.Tensor:
        if isinstance(frame, np.ndarray) and frame.dtype == np.uint8:  # OpenCV's decoded frame: (H, W) / (H, W, 3)
            frame = frame_to_grey(frame) if self.channels == 1 else frame_to_tensor(frame)
        elif isinstance(frame, np.ndarray):
            frame = torch.from_numpy(frame)
        if not isinstance(frame, torch.Tensor) or frame.dim() not in (3, 4) or (frame.dim() == 4 and
                                                                                 frame.shape[0] != 1):
            got = tuple(frame.shape) if isinstance(frame, torch.Tensor) else type(frame).__name__
            raise ShapeError(f"a frame must be (C, H, W) or (1, C, H, W), got {got}")
        image = frame if frame.dim() == 4 else frame[None]
        self._check_size(tuple(image.shape))
        if not torch.is_floating_point(image):
            image = image.float() / 255.0
        return self._model_channels(image, to_grey)

    def _thumbnail(self, image: torch.Tensor) -> np.ndarray:
        """The cut test's 8 x 8 block means: OpenCV's area resize of a float CPU frame (the same means as torch's
        average pooling to float rounding, from a faster kernel on one thread), torch's pooling elsewhere."""
        grey = to_grey(image)
        h, w = grey.shape[-2:]
        if grey.device.type == "cpu" and grey.dtype in (torch.float32, torch.float64) or min(h, w) < 8:
            return block_means(grey[0, 0].numpy(force=True))
        return F.avg_pool2d(grey, 8)[0, 0].numpy(force=True)

    def push(self, frame: torch.Tensor | np.ndarray) -> StreamResult:
        """The depth of the next frame (thread-safe: concurrent pushes run one after the other).

        Args:
            frame: (C, H, W) or (1, C, H, W) float in [0, 1], or a uint8 (H, W) / (H, W, 3) BGR array.

        Returns:
            StreamResult(depth, valid, confidence (1, 1, H, W_ref) tensors each, frame, milliseconds, keyframe).

        Raises:
            ShapeError: a frame of the wrong size, channels or type.
        """
        # an ONNX stream's own tensor work on one torch thread (the module docstring); a torch model keeps them all
        side = thread_plan().side
        with torch_threads(side) if self.backend == "onnx" else contextlib.nullcontext():
            return super().push(frame)

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
