"""The request index of the ONNX cache: a graph found from what was asked, without building the model."""

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
    assert recall(key, cache_dir=tmp_path / "onnx") == (graph, "a model", None)
    # a sequence's request: the per-frame graph and the temporal graph that tracks between its key frames
    tracker = graph.with_name("4567.onnx")
    tracker.write_bytes(b"temporal graph")
    remember("seq", graph, "a model, tracked", temporal=tracker, cache_dir=tmp_path / "onnx")
    assert recall("seq", cache_dir=tmp_path / "onnx") == (graph, "a model, tracked", tracker)
    tracker.unlink()  # either graph gone: not served
    assert recall("seq", cache_dir=tmp_path / "onnx") is None
    graph.unlink()  # a graph removed from the cache: the request is not served
    assert recall(key, cache_dir=tmp_path / "onnx") is None
    index.write_text("{not json")
    assert recall(key, cache_dir=tmp_path / "onnx") is None
