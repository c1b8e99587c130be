"""The cache of exported graphs: each model's graph exported once per rig, options, channels, opset, package version
and source (:func:`onnx_session`), and a request index (:func:`remember`, :func:`recall`) that finds a cached graph
from what a caller asked for (rig, range, options), without building the torch model that resolves it.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from torch import nn

from prismstereo.export.onnx import DEFAULT_OPSET, OnnxDepth, export_onnx, graph_metadata, source_digest
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.io import replacing

if TYPE_CHECKING:
    from prismstereo.depth.temporal import TemporalOptions

__all__ = ["cache_directory", "cache_path", "export_cached", "onnx_session", "request_key", "remember", "recall",
           "CachedGraph"]


def cache_directory() -> Path:
    """Where :func:`onnx_session` keeps exported graphs: ``$PRISMSTEREO_CACHE`` or
    ``~/.cache/prismstereo/onnx``.

    Example:
        >>> cache_directory().name
        'onnx'
    """
    root = os.environ.get("PRISMSTEREO_CACHE")
    return Path(root) / "onnx" if root else Path.home() / ".cache" / "prismstereo" / "onnx"


_SESSIONS: dict[tuple[str, int, bool], OnnxDepth] = {}


def cache_path(model: nn.Module, *, channels: int = 1, opset: int = DEFAULT_OPSET,
               temporal: TemporalOptions | None = None, cache_dir: str | Path | None = None) -> Path:
    """The file of ``model``'s graph in the cache of :func:`onnx_session`: ``<hash>.onnx`` in ``cache_dir`` (default
    :func:`cache_directory`), the hash of the graph's metadata (the model's description, rig, channels, opset,
    temporal options, package version and source digest).

    Example:
        >>> from prismstereo.model import PrismStereo
        >>> cache_path(PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0)), cache_dir="c").suffix
        '.onnx'
    """
    meta = graph_metadata(model, channels, opset, temporal)
    directory = Path(cache_dir) if cache_dir is not None else cache_directory()
    return directory / f"{hashlib.sha256(json.dumps(meta, sort_keys=True).encode()).hexdigest()[:16]}.onnx"


def export_cached(model: nn.Module, path: Path, *, channels: int = 1, opset: int = DEFAULT_OPSET,
                  temporal: TemporalOptions | None = None) -> Path:
    """``model``'s graph at ``path`` (a cache file of :func:`onnx_session`), exported unless the file exists: written
    under a temporary name and renamed, so a concurrent reader never sees half a file.

    Example:
        >>> from prismstereo.model import PrismStereo
        >>> import tempfile; path = Path(tempfile.mkdtemp()) / "onnx" / "graph.onnx"
        >>> export_cached(PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0)), path).is_file()
        True
    """
    if not path.is_file():
        with replacing(path) as partial:
            export_onnx(model, partial, channels=channels, opset=opset, temporal=temporal)
    return path


def onnx_session(model: nn.Module, *, channels: int = 1, opset: int = DEFAULT_OPSET, threads: int = 2,
                 cache_dir: str | Path | None = None, spinning: bool = True,
                 temporal: TemporalOptions | None = None) -> OnnxDepth:
    """The exported graph of ``model`` in onnxruntime, exported once per rig, options, channels, opset and
    package version (a file ``<hash>.onnx`` in ``cache_dir``, default :func:`cache_directory`) and kept per
    process.

    Args:
        model: a :class:`~prismstereo.model.PrismStereo`.
        channels: input channels (1 or 3).
        opset: ONNX opset of a new export.
        threads: onnxruntime intra-op threads.
        cache_dir: directory of cached exports.
        spinning: see :class:`OnnxDepth`.
        temporal: None, or :class:`~prismstereo.depth.temporal.TemporalOptions`: the temporal graph
            (:func:`export_onnx`).

    Returns:
        OnnxDepth.

    Example:
        >>> from prismstereo.model import PrismStereo
        >>> import tempfile; cache = tempfile.mkdtemp()
        >>> model = PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0))
        >>> onnx_session(model, cache_dir=cache) is onnx_session(model, cache_dir=cache)
        True
    """
    path = cache_path(model, channels=channels, opset=opset, temporal=temporal, cache_dir=cache_dir)
    key = (str(path), threads, spinning)
    if key in _SESSIONS:
        return _SESSIONS[key]
    export_cached(model, path, channels=channels, opset=opset, temporal=temporal)
    runner = OnnxDepth(path, threads=threads, spinning=spinning)
    _SESSIONS[key] = runner
    return runner


class CachedGraph(NamedTuple):
    """A cached graph found by its request: its file, the summary of the model that exported it and, for sequences
    under the temporal prior, the file of the temporal graph that tracks between its key frames (else None)."""

    path: Path
    summary: str
    temporal: Path | None = None


def request_key(rig: BiPrismRig, request: dict[str, Any], *, channels: int = 1, opset: int = DEFAULT_OPSET) -> str:
    """The cache's name for a request: a hash of the rig, ``request`` (what the caller asked for, before the model
    resolves its defaults: e.g. the range and the options as given; JSON-serialisable), the channels, the opset,
    the package version and the source digest.

    Example:
        >>> len(request_key(thesis_setup1(), {"z_range_mm": [400.0, 700.0], "config": "accurate"}))
        16
    """
    from prismstereo import __version__

    blob = json.dumps({"rig": rig.to_dict(), "request": request, "channels": channels, "opset": opset,
                       "version": __version__, "source": source_digest()}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _index(key: str, cache_dir: str | Path | None) -> Path:
    directory = Path(cache_dir) if cache_dir is not None else cache_directory()
    return directory / "requests" / f"{key}.json"


def remember(key: str, graph: str | Path, summary: str, *, temporal: str | Path | None = None,
             cache_dir: str | Path | None = None) -> Path:
    """Record that the request ``key`` (:func:`request_key`) is served by the cached ``graph`` (and for sequences
    the cached ``temporal`` graph beside it), with the model's ``summary`` line; returns the index file.

    Example:
        >>> remember("0123456789abcdef", "graph.onnx", "a model", cache_dir="cache")  # doctest: +SKIP
    """
    path = _index(key, cache_dir)
    with replacing(path) as partial:
        entry = {"graph": Path(graph).name, "summary": summary}
        if temporal is not None:
            entry["temporal"] = Path(temporal).name
        partial.write_text(json.dumps(entry) + "\n")
    return path


def recall(key: str, *, cache_dir: str | Path | None = None) -> CachedGraph | None:
    """The cached graph of the request ``key``, or None if it was never remembered or its graph (or temporal graph)
    is gone.

    Example:
        >>> recall("no such request", cache_dir="/nonexistent") is None
        True
    """
    path = _index(key, cache_dir)
    try:
        entry = json.loads(path.read_text())
        graph = path.parent.parent / entry["graph"]
        summary = str(entry["summary"])
        temporal = None if entry.get("temporal") is None else path.parent.parent / entry["temporal"]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    if not graph.is_file() or (temporal is not None and not temporal.is_file()):
        return None
    return CachedGraph(graph, summary, temporal)
