"""Depth of a stream of frames, for applications: one model (torch or its exported ONNX graph), frames pushed one
at a time from any thread, per-frame timing.

:class:`DepthStream` wraps a :class:`~prismstereo.model.PrismStereo` (or any module returning a
:class:`~prismstereo.model.DepthResult`) or an ONNX file written by :func:`~prismstereo.export.export_onnx`
(run by :class:`~prismstereo.export.OnnxDepth`). Frames are processed in the order they are pushed; a lock
serialises concurrent pushes (a capture thread and a UI thread may both call :meth:`DepthStream.push`).
Frames may be (C, H, W) / (1, C, H, W) tensors in [0, 1] or OpenCV's decoded uint8 (H, W) / (H, W, 3) BGR arrays;
colour is converted to grey when the model takes one channel.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import torch
from torch import nn

from prismstereo.errors import OptionError, ShapeError
from prismstereo.video import frame_to_tensor

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
        milliseconds: time of the depth computation (the model or graph alone).
    """

    depth: torch.Tensor
    valid: torch.Tensor
    confidence: torch.Tensor
    frame: int
    milliseconds: float


class DepthStream:
    """Depth frame after frame from one model.

    Args:
        model: a torch module returning a :class:`~prismstereo.model.DepthResult` for (1, C, H, W) images, the
            path of an exported ONNX graph (``.onnx``) or an :class:`~prismstereo.export.OnnxDepth` session.
        threads: onnxruntime intra-op threads (ONNX graphs only).
        spinning: onnxruntime thread spinning (ONNX graphs only; see :class:`~prismstereo.export.OnnxDepth`).

    Attributes:
        backend: 'torch' or 'onnx'.
        channels, height, width: the input the model expects (torch: from its rig; ONNX: from its metadata).
        frames: frames processed so far.
        times_ms: per-frame computation times (ms), in order.

    Raises:
        OptionError: a model that is neither a module with a rig nor an ``.onnx`` path.

    Example:
        >>> from prismstereo.model import PrismStereo
        >>> stream = DepthStream(PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0)))
        >>> out = stream.push(torch.rand(3, 48, 64))
        >>> out.depth.shape, out.frame, stream.frames
        (torch.Size([1, 1, 48, 32]), 0, 1)
    """

    def __init__(self, model: nn.Module | str | Path | OnnxDepth, *, threads: int = 2, spinning: bool = True) -> None:
        self._lock = threading.Lock()
        self.frames = 0
        self.times_ms: list[float] = []
        from prismstereo.export import OnnxDepth

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

    def _prepare(self, frame: torch.Tensor | np.ndarray) -> torch.Tensor:
        if isinstance(frame, np.ndarray):  # OpenCV's decoded frame: uint8 (H, W) or (H, W, 3) BGR
            frame = frame_to_tensor(frame)
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
            from kornia.color import rgb_to_grayscale

            image = rgb_to_grayscale(image)
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
        image = self._prepare(frame)
        with self._lock:
            t0 = time.perf_counter()
            if self.backend == "torch":
                with torch.inference_mode():
                    res = self._runner(image)
            else:
                res = self._runner(image)
            ms = 1000.0 * (time.perf_counter() - t0)
            number = self.frames
            self.frames += 1
            self.times_ms.append(ms)
        return StreamResult(res.depth, res.valid, res.confidence, number, ms)

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
