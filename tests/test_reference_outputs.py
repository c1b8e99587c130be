"""The model's outputs and exported graphs are frozen (``tests/data/reference_outputs.json``,
``reference_graphs.json``, written by ``tests/data/reference_cases.py``, one entry per host): a refactoring must keep
every output bitwise and every graph node for node; a change of algorithm regenerates them in its own commit and
says what it changed."""

import json
import sys
from pathlib import Path

import pytest
import torch

from prismstereo.threads import torch_threads

sys.path.insert(0, str(Path(__file__).parent / "data"))
import reference_cases  # noqa: E402

STORED = json.loads(reference_cases.PATH.read_text())  # {host: {case: entry}}
GRAPHS = json.loads(reference_cases.GRAPHS.read_text())
CASES = {name: (model, capture) for name, model, capture in reference_cases.cases()}


def test_every_case_is_stored_for_every_host():
    for host in STORED:
        assert sorted(CASES) == sorted(STORED[host]), host
    for host in GRAPHS:
        assert sorted(name for name, _ in reference_cases.graph_cases()) == sorted(GRAPHS[host]), host


@pytest.mark.parametrize("name", sorted(CASES))
def test_outputs_are_bitwise_unchanged(name):
    """Bitwise the stored outputs of this host, or within float rounding of every host's where it has none."""
    model, capture = CASES[name]
    with torch.inference_mode(), torch_threads(1):  # as the stored outputs were computed
        now = reference_cases.describe(model().eval()(capture()))
    assert reference_cases.verdict(STORED, name, now) == []


@pytest.mark.parametrize("name", sorted({name for graphs in GRAPHS.values() for name in graphs}))
def test_exported_graphs_are_unchanged_node_for_node(name, export_once):
    model = dict(reference_cases.graph_cases())[name]
    with torch_threads(1):  # as the stored graphs were built (shared with tests/export where it is the same model)
        now = reference_cases.graph_digest(export_once(model()))
    assert reference_cases.verdict(GRAPHS, name, now) == []


def test_a_host_without_an_entry_is_held_to_float_rounding(monkeypatch):
    """The fallback for a host without an entry still catches a changed algorithm: a different count or a sum
    beyond rounding fails, rounding passes; a host with an entry is held to its bits."""
    name = sorted(CASES)[0]
    stored = {"other host": {name: {"depth": {"sha256": "a", "shape": [1], "dtype": "float32", "sum": 1000.0,
                                               "finite": 10}, "valid": {"sha256": "b", "shape": [1], "dtype": "bool",
                                                                        "count": 100}}}}
    rounded = {"depth": {"sha256": "c", "shape": [1], "dtype": "float32", "sum": 1000.000001, "finite": 10},
               "valid": {"sha256": "d", "shape": [1], "dtype": "bool", "count": 101}}
    monkeypatch.setattr(reference_cases, "host", lambda: "this host")
    assert reference_cases.verdict(stored, name, rounded) == []
    moved = {**rounded, "depth": {**rounded["depth"], "sum": 1000.1}}
    assert reference_cases.verdict(stored, name, moved) == ["other host: depth: sum 1000.0 -> 1000.1"]
    fewer = {**rounded, "valid": {**rounded["valid"], "count": 90}}
    assert reference_cases.verdict(stored, name, fewer) == ["other host: valid: count 100 -> 90"]
    stored["this host"] = {name: rounded}
    assert reference_cases.verdict(stored, name, rounded) == []
    assert reference_cases.verdict(stored, name, moved) == ["not bitwise this host's (this host)"]
    assert reference_cases.verdict(stored, "nothing", rounded) == ["not stored"]


def test_graph_digest_ignores_names_but_not_values(tmp_path):
    import onnx
    from onnx import helper, numpy_helper

    def graph(names: tuple[str, str], value: float) -> Path:
        x = helper.make_tensor_value_info("x", onnx.TensorProto.FLOAT, [1])
        y = helper.make_tensor_value_info(names[1], onnx.TensorProto.FLOAT, [1])
        c = numpy_helper.from_array(torch.tensor([value]).numpy(), names[0])
        node = helper.make_node("Add", ["x", names[0]], [names[1]], name=names[0] + "_node")
        path = tmp_path / f"{len(names[0])}_{value}.onnx"
        onnx.save(helper.make_model(helper.make_graph([node], "g", [x], [y], [c])), str(path))
        return path

    a = reference_cases.graph_digest(graph(("c", "y"), 1.0))
    assert a == reference_cases.graph_digest(graph(("/binned/c", "out"), 1.0))
    assert reference_cases.graph_digest(graph(("c", "y"), 2.0))["sha256"] != a["sha256"]
