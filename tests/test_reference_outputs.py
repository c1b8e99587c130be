"""The model's outputs and exported graphs are frozen (``tests/data/reference_outputs.json``,
``reference_graphs.json``, written by ``tests/data/reference_cases.py``): a refactoring must keep every output
bitwise and every graph node for node; a change of algorithm regenerates them in its own commit and says what
it changed."""

import json
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent / "data"))
import reference_cases  # noqa: E402

STORED = json.loads(reference_cases.PATH.read_text())
GRAPHS = json.loads(reference_cases.GRAPHS.read_text())
CASES = {name: (model, capture) for name, model, capture in reference_cases.cases()}


def test_every_case_is_stored():
    assert sorted(CASES) == sorted(STORED)
    assert sorted(name for name, _ in reference_cases.graph_cases()) == sorted(GRAPHS)


@pytest.mark.parametrize("name", sorted(STORED))
def test_outputs_are_bitwise_unchanged(name):
    model, capture = CASES[name]
    with torch.inference_mode():
        now = reference_cases.describe(model().eval()(capture()))
    for field in reference_cases.FIELDS:
        assert now[field] == STORED[name][field], f"{name}: {field} changed"


@pytest.mark.parametrize("name", sorted(GRAPHS))
def test_exported_graphs_are_unchanged_node_for_node(name, export_once):
    model = dict(reference_cases.graph_cases())[name]
    now = reference_cases.graph_digest(export_once(model()))  # shared with tests/export where it is the same model
    assert now == GRAPHS[name]


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
