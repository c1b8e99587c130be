"""The names the command line and the library share, importable without torch: the model kinds, the backends and
the depth file formats.

The modules that own them re-export them (:data:`prismstereo.models.MODEL_KINDS`,
:data:`prismstereo.predictor.BACKENDS`, :data:`prismstereo.io.DEPTH_FILE_FORMATS`); ``prismstereo depth`` builds
its parser from here, so asking for its help or parsing its flags does not import torch.
"""

from __future__ import annotations

from typing import Literal

__all__ = ["BACKENDS", "DEPTH_FILE_FORMATS", "DEPTH_SUFFIXES", "MODEL_KINDS", "Backend", "ModelKind"]

ModelKind = Literal["hybrid", "classical", "learned"]
MODEL_KINDS: tuple[str, ...] = ("hybrid", "classical", "learned")
"""The depth models :func:`~prismstereo.models.build_model` builds."""

Backend = Literal["torch", "onnx"]
BACKENDS: tuple[str, ...] = ("torch", "onnx")
"""Where a :class:`~prismstereo.predictor.Predictor` runs a model: torch, or its exported graphs in onnxruntime."""

DEPTH_FILE_FORMATS: tuple[str, ...] = ("npy", "png", "tiff")
"""The depth map files :func:`~prismstereo.io.write_depth` writes."""
DEPTH_SUFFIXES: dict[str, str] = {".npy": "npy", ".png": "png", ".tif": "tiff", ".tiff": "tiff"}
"""A depth file's format by its suffix."""
