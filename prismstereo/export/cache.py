"""The cache of exported graphs: request -> graphs, in one place.

:func:`cached_graphs` is the one way to a model's graphs: the per-frame graph and, for videos, the temporal graph
of the band the model offers (its ``tracker``). Each is exported once per rig, model description, channels, opset,
temporal options, package version and source (:func:`cache_path`) into :func:`cache_directory`, written under a
temporary name and renamed, so a concurrent reader never sees half a file. A model asked for by its
:class:`~prismstereo.models.ModelSpec` is also indexed by that request (:func:`request_key`, :func:`remember`,
:func:`recall`): the next time the same request is served from the cache without building the torch model.
:class:`~prismstereo.predictor.Predictor` (its ONNX backend), ``prismstereo depth --backend onnx`` and
``prismstereo export`` go through it.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import TYPE_CHECKING

from prismstereo.export.graph import DEFAULT_OPSET, export_onnx
from prismstereo.export.index import (
    GraphFiles,
    _directory,
    cache_directory,
    recall,
    remember,
    request_key,
    source_digest,
)
from prismstereo.io import replacing

if TYPE_CHECKING:
    from prismstereo.classical import TemporalDepth, TemporalOptions
    from prismstereo.models import DepthModel, ModelSpec

__all__ = ["GraphFiles", "cache_directory", "cache_path", "cached_graphs", "export_cached", "recall", "remember",
           "request_key"]


def cache_path(model: DepthModel, *, channels: int = 1, opset: int = DEFAULT_OPSET,
               temporal: TemporalOptions | None = None, cache_dir: str | Path | None = None) -> Path:
    """The file of ``model``'s graph (with ``temporal``: of its temporal band's graph) in the cache: ``<hash>.onnx``
    in ``cache_dir`` (default :func:`cache_directory`), the hash of the model's description and rig, the channels,
    the opset, the temporal options, the package version and the source digest.

    Example:
        >>> from prismstereo.classical import PrismStereo
        >>> cache_path(PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0)), cache_dir="c").suffix
        '.onnx'
    """
    from prismstereo import __version__

    blob = json.dumps({"model": model.describe(), "rig": model.rig.to_dict(), "channels": channels, "opset": opset,
                       "temporal": None if temporal is None else temporal.to_dict(), "version": __version__,
                       "source": source_digest()}, sort_keys=True)
    return _directory(cache_dir) / f"{hashlib.sha256(blob.encode()).hexdigest()[:16]}.onnx"


def export_cached(model: DepthModel, path: Path, *, channels: int = 1, opset: int = DEFAULT_OPSET,
                  temporal: TemporalOptions | TemporalDepth | None = None) -> Path:
    """``model``'s graph at ``path`` (a cache file, :func:`cache_path`), exported unless the file exists: written
    under a temporary name and renamed, so a concurrent reader never sees half a file.

    Example:
        >>> from prismstereo.classical import PrismStereo
        >>> import tempfile; path = Path(tempfile.mkdtemp()) / "onnx" / "graph.onnx"
        >>> export_cached(PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0)), path).is_file()
        True
    """
    if not path.is_file():
        with replacing(path) as partial:
            export_onnx(model, partial, channels=channels, opset=opset, temporal=temporal)
    return path


def cached_graphs(model: DepthModel | ModelSpec, *, temporal: TemporalOptions | None = None, channels: int = 1,
                  opset: int = DEFAULT_OPSET, cache_dir: str | Path | None = None) -> GraphFiles:
    """A model's graphs from the cache, exported into it the first time: the per-frame graph and, with
    ``temporal``, the temporal graph of the band the model offers (none for a model without one).

    Args:
        model: a built model, or a :class:`~prismstereo.models.ModelSpec`: then the graphs of the same request
            are served without building the model (:func:`recall`), and a new request is remembered.
        temporal: the temporal band's options, or None (the per-frame graph only).
        channels: input channels of the graphs (1 or 3).
        opset: ONNX opset of a new export.
        cache_dir: the cache (default :func:`cache_directory`).

    Returns:
        GraphFiles.

    Example:
        >>> from prismstereo.models import ModelSpec
        >>> import tempfile; cache = tempfile.mkdtemp()
        >>> spec = ModelSpec(rig=thesis_setup1().downscaled(16), z_range=(400.0, 700.0))
        >>> first, again = cached_graphs(spec, cache_dir=cache), cached_graphs(spec, cache_dir=cache)
        >>> first.path == again.path, first.cached, again.cached
        (True, False, True)
    """
    from prismstereo.models import ModelSpec

    if not isinstance(model, ModelSpec):
        return _export(model, temporal, channels, opset, cache_dir)
    request = {**model.request(), "temporal": None if temporal is None else temporal.to_dict()}
    key = request_key(model.rig, request, channels=channels, opset=opset)
    found = recall(key, cache_dir=cache_dir)
    if found is not None:
        return found
    files = _export(model.build(), temporal, channels, opset, cache_dir)
    remember(key, files.path, files.summary, temporal=files.temporal, cache_dir=cache_dir)
    return files


def _export(model: DepthModel, temporal: TemporalOptions | None, channels: int, opset: int,
            cache_dir: str | Path | None) -> GraphFiles:
    """A built model's graphs in the cache (:func:`cached_graphs`)."""
    from prismstereo.models import describe_model

    path = export_cached(model, cache_path(model, channels=channels, opset=opset, cache_dir=cache_dir),
                         channels=channels, opset=opset)
    tracker = None if temporal is None else model.tracker(temporal)
    band = None
    if tracker is not None:
        band = export_cached(model, cache_path(model, channels=channels, opset=opset, temporal=temporal,
                                               cache_dir=cache_dir), channels=channels, opset=opset, temporal=tracker)
    return GraphFiles(path, describe_model(model, temporal, tracker), band)
