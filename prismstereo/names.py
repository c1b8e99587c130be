"""The names the command line and the library share, importable without torch: the model kinds, the backends and
the depth file formats, and the exported graphs' inputs and outputs.

The modules that own them re-export them (:data:`prismstereo.models.MODEL_KINDS`,
:data:`prismstereo.predictor.BACKENDS`, :data:`prismstereo.io.DEPTH_FILE_FORMATS`); ``prismstereo depth`` builds
its parser from here, so asking for its help or parsing its flags does not import torch.
"""

from __future__ import annotations

from typing import Literal

__all__ = ["BACKENDS", "DEPTH_FILE_FORMATS", "DEPTH_SUFFIXES", "INPUT_NAME", "LAST_STAGES", "MODEL_KINDS",
           "NEXT_PRIOR_NAMES", "OUTPUT_NAMES", "PRIOR_NAMES", "Backend", "ModelKind"]

ModelKind = Literal["hybrid", "classical", "learned"]
MODEL_KINDS: tuple[str, ...] = ("hybrid", "classical", "learned")
"""The depth models :func:`~prismstereo.models.build_model` builds."""

LAST_STAGES: tuple[str, ...] = ("exact", "learned")
"""The hybrid's last stages (:class:`~prismstereo.learned.HybridStereo`'s ``last_stage``)."""

Backend = Literal["torch", "onnx"]
BACKENDS: tuple[str, ...] = ("torch", "onnx")
"""Where a :class:`~prismstereo.predictor.Predictor` runs a model: torch, or its exported graphs in onnxruntime."""

DEPTH_FILE_FORMATS: tuple[str, ...] = ("npy", "png", "tiff")
"""The depth map files :func:`~prismstereo.io.write_depth` writes."""
DEPTH_SUFFIXES: dict[str, str] = {".npy": "npy", ".png": "png", ".tif": "tiff", ".tiff": "tiff"}
"""A depth file's format by its suffix."""

INPUT_NAME = "image"
"""An exported graph's input, (B, C, H, W) float32 (:mod:`prismstereo.export.graph`)."""
OUTPUT_NAMES: tuple[str, ...] = ("depth_mm", "valid", "confidence")
"""An exported graph's outputs, (B, 1, H, W_ref) each."""
PRIOR_NAMES: tuple[str, ...] = ("prior_inverse_depth", "prior_placed")
"""A temporal graph's prior inputs (a :class:`~prismstereo.classical.BandPrior`)."""
NEXT_PRIOR_NAMES: tuple[str, ...] = ("next_inverse_depth", "next_placed")
"""A temporal graph's outputs beside :data:`OUTPUT_NAMES`: the next frame's prior."""
