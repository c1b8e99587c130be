"""Helpers of the benchmark scripts whose numbers go to docs/benchmarks.md."""

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from default_chain import score  # noqa: E402
from dense_depth import best_coverage, edge_strength, jump_distance, model_config  # noqa: E402
from fit_confidence import fit_options  # noqa: E402

from prismstereo.classical.config import preset  # noqa: E402


def test_jump_distance_of_a_step():
    depth = torch.full((6, 10), 500.0)
    depth[:, 5:] = 520.0  # 4 % farther: a jump between columns 4 and 5
    distance = jump_distance(depth)
    assert distance.shape == (6, 10)
    assert distance[:, 4:6].eq(0).all()  # both sides of the jump
    torch.testing.assert_close(distance[0, :4], torch.tensor([4.0, 3.0, 2.0, 1.0], dtype=torch.float64))
    torch.testing.assert_close(distance[0, 6:], torch.tensor([1.0, 2.0, 3.0, 4.0], dtype=torch.float64))


def test_jump_distance_ignores_steps_below_the_threshold():
    depth = torch.full((4, 8), 500.0)
    depth[:, 4:] = 504.0  # 0.8 %
    assert torch.isinf(jump_distance(depth)).all()
    assert jump_distance(depth, jump=0.005)[:, 3:5].eq(0).all()
    rows = torch.full((8, 4), 500.0)
    rows[4:] = 450.0  # a jump between rows counts too
    assert jump_distance(rows)[3:5].eq(0).all()


def test_model_config():
    assert model_config('a={"downsample": 1}') == ("a", {"downsample": 1})
    name, options = model_config('no fill={"preset": "dense", "dense_fill": 0}')
    assert name == "no fill"
    assert options == preset("dense").with_options(dense_fill=0).to_options()
    assert model_config('c>=0.1={"min_confidence": 0.1}') == ("c>=0.1", {"min_confidence": 0.1})
    for bad, message in (("nothing", "NAME=JSON"), ("a={", "not JSON"), ("a=[1]", "JSON object")):
        with pytest.raises(SystemExit, match=message):
            model_config(bad)


def test_best_coverage():
    confidence = torch.tensor([0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2])
    right = torch.tensor([True, True, True, False, True, True, False, False])
    cover, threshold, perfect = best_coverage(confidence, right, 10, bad=0.2)
    # the 5 most confident are 1/5 wrong; the 6th keeps 1/6; the 7th 2/7 > 0.2
    assert (cover, threshold) == (60.0, pytest.approx(0.4))
    assert perfect == pytest.approx(100 * min(8, 5 / 0.8) / 10)
    # ties: a threshold keeps every pixel at its confidence or none of them
    tied = best_coverage(torch.tensor([0.9, 0.5, 0.5]), torch.tensor([True, True, False]), 3, bad=0.3)
    assert tied[:2] == (pytest.approx(100 / 3), pytest.approx(0.9))
    assert best_coverage(torch.tensor([0.9]), torch.tensor([False]), 1)[0] == 0.0


def test_fit_options_reject_edges_only_where_the_preset_leaves_them():
    """The shipped DEFAULT_WEIGHTS were fitted on the default chain with its final band rejecting its edges; the
    fast preset keeps its clamp, a dense preset its own rule, and 'preset' changes nothing."""
    accurate = fit_options("accurate")
    assert accurate["band_edges"] == "reject"
    assert accurate == preset("accurate").with_options(band_edges="reject").to_options()
    assert fit_options("accurate", "clamp")["band_edges"] == "clamp"
    assert fit_options("accurate", "preset") == preset("accurate").to_options()
    for name in ("fast", "dense"):
        assert fit_options(name) == preset(name).to_options()
    from prismstereo import thesis_setup1
    from prismstereo.classical.model import PrismStereo

    rig = thesis_setup1().downscaled(8)
    assert PrismStereo(rig, (400.0, 700.0), fit_options("accurate")).final.config.search.band_edges == "reject"
    assert PrismStereo(rig, (400.0, 700.0), fit_options("fast")).final.config.validity.confidence_weights == "clamped"


def test_edge_strength_tells_marked_jumps_from_hidden_ones():
    g = torch.Generator().manual_seed(0)
    image = 0.5 + 0.02 * torch.rand(1, 40, 40, generator=g)  # faint texture
    depth = torch.full((40, 40), 500.0)
    depth[:, 20:] = 550.0
    covisible = torch.ones(40, 40, dtype=torch.bool)
    distance = jump_distance(depth)
    hidden = edge_strength(image, distance, covisible)  # the same texture everywhere
    marked = image.clone()
    marked[..., 20:] += 0.3  # the jump is an edge of the image too
    shown = edge_strength(marked, distance, covisible)
    assert shown[0] > 85 and shown[1] == 0
    assert hidden[0] < 75 and hidden[1] > 20
    nan = edge_strength(image, jump_distance(torch.full((40, 40), 500.0)), covisible)
    assert all(v != v for v in nan)


def test_default_chain_score_counts_valid_and_dense_pixels():
    from prismstereo.depth.result import DepthResult

    truth = torch.full((1, 1, 2, 5), 500.0, dtype=torch.float64)
    depth = torch.tensor([[[[500.0, 501.0, 510.0, 500.0, 520.0], [500.0, 500.0, 500.0, 500.0, 500.0]]]])
    valid = torch.tensor([[[[True, True, True, False, False], [True, True, True, True, True]]]])
    confidence = torch.tensor([[[[0.9, 0.8, 0.7, 0.3, 0.2], [0.9, 0.9, 0.9, 0.9, 0.0]]]])
    covisible = torch.ones(1, 1, 2, 5, dtype=torch.bool)
    covisible[0, 0, 1, 3] = False
    rel = (depth.double() - truth).abs() / truth
    r = score(DepthResult(depth, valid, confidence, depth, depth), rel, covisible)
    assert r["valid"] == pytest.approx(100 * 7 / 9) and r["valid bad"] == pytest.approx(100 / 7)  # 510 is 2 % off
    assert r["dense"] == pytest.approx(100 * 8 / 9) and r["dense bad"] == pytest.approx(100 * 2 / 8)
    # the most confident first: four 500s (0.9), 501 (0.8), then 510 (0.7: 1 of 6 wrong > 3 %): 5 of 9 kept
    assert r["@3"] == pytest.approx(100 * 5 / 9)
    assert r["hidden"] == 1 and r["hidden bad"] == 0.0  # the valid pixel the other half cannot see, right


def _code_strings(path: Path) -> dict[str, str]:
    """The module-level string constants of a benchmark that are Python programs (run as ``python -c CODE`` in a
    fresh process, so the script's own imports do not reach them), concatenations included."""
    import ast

    values: dict[str, str] = {}
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            try:
                value = eval(compile(ast.Expression(node.value), str(path), "eval"), {"__builtins__": {}}, values)
            except Exception:  # not a constant expression of strings
                continue
            if isinstance(value, str):
                values[node.targets[0].id] = value
    programs = {}
    for name, value in values.items():
        try:
            ast.parse(value)
        except SyntaxError:
            continue
        if "import " in value:
            programs[name] = value
    return programs


def test_subprocess_programs_of_the_benchmarks_define_every_name():
    """Every ``python -c`` program of a benchmark imports what it calls (ruff's undefined-name rule, F821)."""
    import subprocess

    root = Path(__file__).resolve().parents[1] / "benchmarks"
    programs = {f"{path.name}:{name}": code for path in sorted(root.glob("*.py"))
                for name, code in _code_strings(path).items()}
    assert {"default_chain.py:MEMORY", "onnx_speed.py:TORCH_RSS", "onnx_speed.py:ORT_RSS"} <= set(programs)
    for where, code in programs.items():
        run = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "--isolated", "--select", "F821",
                              "--stdin-filename", "program.py", "-"], input=code, capture_output=True, text=True)
        assert run.returncode == 0, f"{where}: {run.stdout}{run.stderr}"
