"""The request index of the ONNX cache: a graph found from what was asked, without building the model."""

import pytest

from prismstereo import thesis_setup1
from prismstereo.export import recall, remember, request_key


def test_request_key_remember_and_recall(tmp_path):
    rig = thesis_setup1().downscaled(8)
    request = {"config": {"search": {"downsample": 2}}, "z_range_mm": None}
    key = request_key(rig, request)
    assert key == request_key(rig, dict(reversed(request.items())))  # order-free
    assert key != request_key(rig, {**request, "z_range_mm": [400.0, 700.0]})
    assert key != request_key(rig.replace(alpha_deg=6.0), request) and key != request_key(rig, request, channels=3)
    assert recall(key, cache_dir=tmp_path) is None
    graph = tmp_path / "onnx" / "0123.onnx"
    graph.parent.mkdir()
    graph.write_bytes(b"graph")
    index = remember(key, graph, "a model", cache_dir=tmp_path / "onnx")
    assert index.parent.name == "requests" and not list(index.parent.glob(".*partial*"))
    assert recall(key, cache_dir=tmp_path / "onnx") == (graph, "a model", None, True)
    # a sequence's request: the per-frame graph and the temporal graph that tracks between its key frames
    tracker = graph.with_name("4567.onnx")
    tracker.write_bytes(b"temporal graph")
    remember("seq", graph, "a model, tracked", temporal=tracker, cache_dir=tmp_path / "onnx")
    assert recall("seq", cache_dir=tmp_path / "onnx") == (graph, "a model, tracked", tracker, True)
    tracker.unlink()  # either graph gone: not served
    assert recall("seq", cache_dir=tmp_path / "onnx") is None
    graph.unlink()  # a graph removed from the cache: the request is not served
    assert recall(key, cache_dir=tmp_path / "onnx") is None
    index.write_text("{not json")
    assert recall(key, cache_dir=tmp_path / "onnx") is None


def test_cached_graphs_export_once_and_serve_a_request_without_a_model(tmp_path, monkeypatch):
    """A built model's graphs are exported once into the cache (keyed by its description and options); a model asked
    for by its spec is exported the first time and remembered, then served from the cache without being built; the
    temporal graph is the band's, and a model without a band has none."""
    from prismstereo.classical import PrismStereo, TemporalOptions
    from prismstereo.export import OnnxDepth, cache_path, cached_graphs
    from prismstereo.models import ModelSpec
    from prismstereo.predictor import Predictor

    rig = thesis_setup1().downscaled(16)
    model = PrismStereo(rig, (400.0, 700.0), {"coarse_factor": 2})
    files = cached_graphs(model, cache_dir=tmp_path)
    assert files == cached_graphs(model, cache_dir=tmp_path) and not files.cached and files.temporal is None
    assert files.path == cache_path(model, cache_dir=tmp_path) and len(list(tmp_path.glob("*.onnx"))) == 1
    other = PrismStereo(rig, (300.0, 900.0), {"coarse_factor": 2})
    # another range: another graph (the file cached_graphs keeps a model's graph in is its cache_path, as above)
    assert cache_path(other, cache_dir=tmp_path) != files.path
    tracked = cached_graphs(model, temporal=TemporalOptions(), cache_dir=tmp_path)
    assert tracked.path == files.path and OnnxDepth(tracked.temporal).temporal.downsample == 1
    assert "temporal prior on sequences" in tracked.summary
    single = PrismStereo(rig, (400.0, 700.0))  # one level: no band to track with
    assert cached_graphs(single, temporal=TemporalOptions(), cache_dir=tmp_path).temporal is None
    spec = ModelSpec(rig=rig, kind="classical", z_range=(400.0, 700.0), config={"coarse_factor": 2})
    first = cached_graphs(spec, cache_dir=tmp_path)
    assert not first.cached and first.path == files.path  # the same model: the same graph
    monkeypatch.setattr(PrismStereo, "__init__", lambda *a, **k: pytest.fail("a model was built"))
    again = cached_graphs(spec, cache_dir=tmp_path)
    assert again.cached and again.path == files.path and again.summary == first.summary
    predictor = Predictor(spec, backend="onnx", cache_dir=tmp_path)
    assert predictor.cached and predictor.rig == rig and predictor.z_range == (400.0, 700.0)


def test_the_cache_index_reads_without_torch(tmp_path):
    """A host that only runs cached graphs finds them by request without importing torch."""
    import subprocess
    import sys

    (tmp_path / "onnx").mkdir()
    (tmp_path / "onnx" / "g.onnx").write_bytes(b"graph")
    code = ("import sys; from prismstereo.export.index import recall, remember, source_digest\n"
            f"remember('k', r'{tmp_path / 'onnx' / 'g.onnx'}', 'a model', cache_dir=r'{tmp_path / 'onnx'}')\n"
            f"found = recall('k', cache_dir=r'{tmp_path / 'onnx'}')\n"
            "print(found.path.name, found.summary.replace(' ', '_'), found.cached, len(source_digest()), "
            "'torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["g.onnx", "a_model", "True", "16", "False"]
