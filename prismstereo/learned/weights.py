"""Weights files of the learned models: the CNNs' tensors with the architecture that shapes them and a little
metadata, in one format per model (:func:`write_weights`, :func:`read_weights`, read safely with
``weights_only``); :class:`WeightsError` for a file that cannot be read or does not fit.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import torch

from prismstereo.errors import PrismStereoError

__all__ = ["WeightsError", "read_weights", "state_part", "write_weights"]


class WeightsError(PrismStereoError, ValueError):
    """A weights file that cannot be read or does not fit the model's architecture."""


def write_weights(path: str | Path, fmt: str, architecture: Any, state: dict[str, torch.Tensor],
                  metadata: dict[str, Any]) -> Path:
    """Write a weights file that :func:`read_weights` reads: the format tag ``fmt``, the ``architecture`` dataclass's
    fields, ``state`` (float32 CPU copies) and ``metadata`` (small, plain values); parent folders are created.

    Example:
        >>> import tempfile
        >>> from prismstereo.learned.network import FORMAT, Architecture
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     path = write_weights(Path(tmp) / "w.pt", FORMAT, Architecture(), {}, {"note": "example"})
        ...     read_weights(path, FORMAT, Architecture, "LearnedStereo")[2]
        {'note': 'example'}
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().float().cpu().clone() for k, v in state.items()}
    torch.save({"format": fmt, "architecture": dataclasses.asdict(architecture), "state_dict": state,
                "metadata": metadata}, path)
    return path


def read_weights(path: str | Path, fmt: str, architecture: type, model: str) -> tuple[Any, dict[str, torch.Tensor],
                                                                                     dict[str, Any]]:
    """A weights file of ``model`` (format tag ``fmt``): (``architecture`` (**its stored fields), state_dict,
    metadata), loaded safely (``weights_only``).

    Raises:
        WeightsError: missing or unreadable file, another format, or an invalid architecture.

    Example:
        >>> from prismstereo.learned.network import FORMAT, LEARNED_WEIGHTS, Architecture
        >>> read_weights(LEARNED_WEIGHTS, FORMAT, Architecture, "LearnedStereo")[0].scale
        4
    """
    path = Path(path)
    if not path.is_file():
        raise WeightsError(f"weights file {path} does not exist")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a file it cannot read: say what the file is not
        raise WeightsError(f"{path} is not a {model} weights file (torch.load cannot read it safely: "
                           f"{type(exc).__name__})") from exc
    if not isinstance(blob, dict) or blob.get("format") != fmt or not isinstance(blob.get("state_dict"), dict):
        raise WeightsError(f"{path} is not a {model} weights file (format {fmt!r})")
    try:
        arch = architecture(**blob["architecture"])
    except (TypeError, PrismStereoError) as exc:
        raise WeightsError(f"{path} holds an invalid architecture {blob.get('architecture')!r}: {exc}") from exc
    return arch, blob["state_dict"], dict(blob.get("metadata", {}))


def state_part(state: dict[str, torch.Tensor], name: str) -> dict[str, torch.Tensor]:
    """The entries of a weights file's ``state`` that belong to its module ``name`` (keys ``name.*``), with that
    prefix removed: what the module's ``load_state_dict`` takes (a file holds several modules' tensors).

    Example:
        >>> state_part({"head.out.bias": torch.zeros(1), "half.0.head.bias": torch.ones(2)}, "head")
        {'out.bias': tensor([0.])}
    """
    prefix = f"{name}."
    return {k[len(prefix):]: v for k, v in state.items() if k.startswith(prefix)}
