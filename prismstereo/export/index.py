"""The cache's index, importable without torch: where exported graphs are kept (:func:`cache_directory`), the
digest of the sources that exported them (:func:`source_digest`), and the requests each is remembered by
(:func:`request_key`, :func:`remember`, :func:`recall`). :mod:`prismstereo.export.cache` exports into it; a host that
only runs cached graphs reads it without importing torch.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from prismstereo.io import replacing

if TYPE_CHECKING:
    from prismstereo.geometry.rig import BiPrismRig

__all__ = ["GraphFiles", "cache_directory", "describe_graph", "flags_key", "recall", "remember", "request_key",
           "source_digest"]

DEFAULT_OPSET = 18
"""The ONNX opset of a new export (re-exported by :mod:`prismstereo.export.graph`)."""


class GraphFiles(NamedTuple):
    """A model's graphs in the cache.

    Attributes:
        path: the per-frame graph.
        summary: the model's summary line (:func:`~prismstereo.models.describe_model`, with its temporal band).
        temporal: the temporal graph of the band that tracks between key frames, when temporal options were asked
            for and the model offers a band; else None.
        cached: served by a request remembered before (:func:`recall`), no model built.
    """

    path: Path
    summary: str
    temporal: Path | None = None
    cached: bool = False


def cache_directory() -> Path:
    """Where exported graphs are kept: ``$PRISMSTEREO_CACHE/onnx`` or ``~/.cache/prismstereo/onnx``.

    Example:
        >>> cache_directory().name
        'onnx'
    """
    root = os.environ.get("PRISMSTEREO_CACHE")
    return Path(root) / "onnx" if root else Path.home() / ".cache" / "prismstereo" / "onnx"


def _directory(cache_dir: str | Path | None) -> Path:
    return Path(cache_dir) if cache_dir is not None else cache_directory()


def source_digest() -> str:
    """sha256 (16 hex digits) of the package's Python sources: which code built a graph (stored in its metadata and
    part of the cache's keys, :mod:`prismstereo.export.cache`, so that a changed algorithm or fitted constant is
    exported again instead of served from the cache under an unchanged version number).

    Example:
        >>> len(source_digest())
        16
    """
    digest = hashlib.sha256()
    root = Path(__file__).resolve().parents[1]
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def request_key(rig: BiPrismRig, request: dict[str, Any], *, channels: int = 1, opset: int = DEFAULT_OPSET) -> str:
    """The cache's name for a request: a hash of the rig, ``request`` (what the caller asked for, before the model
    resolves its defaults, JSON-serialisable: :meth:`~prismstereo.models.ModelSpec.request`), the channels, the
    opset, the package version and the source digest.

    Example:
        >>> len(request_key(thesis_setup1(), {"z_range_mm": [400.0, 700.0], "config": "accurate"}))
        16
    """
    from prismstereo import __version__

    blob = json.dumps({"rig": rig.to_dict(), "request": request, "channels": channels, "opset": opset,
                       "version": __version__, "source": source_digest()}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]



def flags_key(flags: dict[str, Any], *, channels: int = 1, opset: int = DEFAULT_OPSET) -> str:
    """The cache's name for a request made by a command's flags (:func:`~prismstereo.cli.model_flags.request_flags`,
    JSON), before any rig or model is built: a hash of the flags, the channels, the opset, the package version and
    the source digest. A command that served such a request remembers its graphs under it (:func:`remember`); the
    same command again recalls them without importing torch.

    Example:
        >>> key = flags_key({"rig": "thesis_setup1", "z_range": None})
        >>> key[:6], len(key)
        ('flags-', 22)
    """
    from prismstereo import __version__

    blob = json.dumps({"flags": flags, "channels": channels, "opset": opset, "version": __version__,
                       "source": source_digest()}, sort_keys=True)
    return "flags-" + hashlib.sha256(blob.encode()).hexdigest()[:16]


def _index(key: str, cache_dir: str | Path | None) -> Path:
    return _directory(cache_dir) / "requests" / f"{key}.json"


def remember(key: str, graph: str | Path, summary: str, *, temporal: str | Path | None = None,
             cache_dir: str | Path | None = None) -> Path:
    """Record that the request ``key`` (:func:`request_key`) is served by the cached ``graph`` (and for videos the
    cached ``temporal`` graph beside it), with the model's ``summary`` line; returns the index file.

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


def recall(key: str, *, cache_dir: str | Path | None = None) -> GraphFiles | None:
    """The cached graphs of the request ``key``, or None if it was never remembered or a graph of it is gone.

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
    return GraphFiles(graph, summary, temporal, cached=True)


def describe_graph(metadata: dict[str, Any]) -> str:
    """One line summarising an exported graph's metadata (for the CLI).

    Example:
        >>> describe_graph({"prismstereo.input_shape": '["B", 1, 48, 64]', "prismstereo.num_hypotheses": "9",
        ...           "prismstereo.z_range_mm": "[400.0, 700.0]", "prismstereo.version": "0.1.0"})
        'input (B, 1, 48, 64), 9 hypotheses over 400.0-700.0 mm, prismstereo 0.1.0'
    """
    shape = ", ".join(str(d) for d in json.loads(metadata["prismstereo.input_shape"]))
    z = json.loads(metadata["prismstereo.z_range_mm"])
    return (f"input ({shape}), {metadata['prismstereo.num_hypotheses']} hypotheses over {z[0]:.1f}-{z[1]:.1f} mm, "
            f"prismstereo {metadata['prismstereo.version']}")
