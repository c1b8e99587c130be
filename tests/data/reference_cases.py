"""The captures and models whose outputs ``reference_outputs.json`` freezes (``tests/test_reference_outputs.py``).

A refactoring that keeps the algorithms must keep every output bitwise: each case stores the SHA-256 of each
:class:`~prismstereo.depth.result.DepthResult` field (float32 / bool bytes) with a few statistics that say how far
a changed output moved, and each exported graph a digest of its nodes (:func:`graph_digest`).

Float rounding differs between CPUs (the vector units torch's and the sweep fit's kernels use), so the files hold
one entry per host (:func:`host`): the outputs must be bitwise one host's, and on a host that has no entry they
must agree with the stored ones to float rounding (:func:`within_rounding`: the same counts and shapes, sums to
1e-5; graphs with the same nodes and operators). Everything runs on one torch thread (the reductions of a build's
float64 fits round differently on two). A change that is meant to alter the numbers regenerates the files
in its own commit, stating the difference it measured; this drops the other hosts' entries, which no longer hold:

    .venv/bin/python tests/data/reference_cases.py             # rewrite the files with this host's outputs only
    .venv/bin/python tests/data/reference_cases.py --add-host  # add (or replace) this host's entry, keep the others
    .venv/bin/python tests/data/reference_cases.py --check     # compare, print the cases that differ
"""

from __future__ import annotations

import argparse
import hashlib
import json
import platform
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import torch

from prismstereo import thesis_setup1, thesis_setup2
from prismstereo.classical.model import PrismStereo
from prismstereo.synthetic import ImageFormation, render, slanted_plane, step_scene
from prismstereo.threads import torch_threads

PATH = Path(__file__).with_name("reference_outputs.json")
GRAPHS = Path(__file__).with_name("reference_graphs.json")
FIELDS = ("depth", "valid", "confidence", "index", "match")


def _capture(rig, scene) -> torch.Tensor:
    return render(rig, scene, ImageFormation(supersample=2, noise_sigma=2 / 255, seed=11)).image


def _shared(build: Callable[[], torch.Tensor]) -> Callable[[], torch.Tensor]:
    """The capture ``build`` renders, rendered once and cloned for each case that uses it (several cases share
    a capture; a render at 1024 x 768 takes longer than most models' forward)."""
    memo: list[torch.Tensor] = []

    def capture() -> torch.Tensor:
        if not memo:
            memo.append(build())
        return memo[0].clone()

    return capture


def cases() -> Iterator[tuple[str, Callable[[], PrismStereo], Callable[[], torch.Tensor]]]:
    """(name, model builder, capture builder) of every frozen case: each preset on the full sensor (a pyramid)
    and on a half-size sensor (coarse-to-fine at full resolution), and single options that take other paths."""
    full, half, half2 = thesis_setup1(), thesis_setup1().downscaled(2), thesis_setup2().downscaled(2)
    z = (400.0, 800.0)
    steps = {id(rig): _shared(lambda rig=rig: _capture(rig, step_scene(rig, 480.0, 700.0, seed=3)))
             for rig in (full, half, half2)}
    slanted = _shared(lambda: _capture(half, slanted_plane(half, 600.0, 20.0, seed=4)))
    step = lambda rig: steps[id(rig)]  # noqa: E731
    slant = lambda rig: slanted  # noqa: E731
    for name in ("accurate", "fast", "dense"):
        yield f"setup1 1024x768 {name}", lambda n=name: PrismStereo(full, z, n), step(full)
    for name in ("accurate", "fast", "dense", "reference"):
        yield f"setup1 512x384 {name}", lambda n=name: PrismStereo(half, z, n), step(half)
    options = {
        "thresholds": {"validity": "thresholds", "smoothing": 0},
        "sweep sampling": {"sampling": "sweep"},
        "census, soft-argmin": {"cost": "census", "refinement": "soft_argmin"},
        "blocks": {"downsample": 2, "full_band": 0},
        "lr check, 8 directions": {"lr_threshold": 1.0, "directions": 8},
        "single rectified level": {"coarse_factor": 1, "sampling": "rectified"},
    }
    for name, kwargs in options.items():
        yield f"setup1 512x384 {name}", lambda k=kwargs: _model(half, z, k), slant(half)
    yield "setup2 512x384 accurate", lambda: PrismStereo(half2, z), step(half2)


def _model(rig, z, options: dict) -> PrismStereo:
    return PrismStereo(rig, z, options)


def describe(result) -> dict:
    """SHA-256 and statistics of each output field."""
    out = {}
    for field in FIELDS:
        a = getattr(result, field).detach().contiguous().numpy()
        entry = {"sha256": hashlib.sha256(a.tobytes()).hexdigest(), "shape": list(a.shape), "dtype": str(a.dtype)}
        if a.dtype == np.bool_:
            entry["count"] = int(a.sum())
        else:
            finite = np.isfinite(a)
            entry["sum"] = float(np.float64(a[finite]).sum())
            entry["finite"] = int(finite.sum())
        out[field] = entry
    return out


def graph_cases() -> Iterator[tuple[str, Callable[[], PrismStereo]]]:
    """(name, model builder) of the exported graphs frozen node for node: a coarse-to-fine model and a pyramid,
    each default and dense."""
    small, pyramid = thesis_setup1().downscaled(8), {"downsample": 2, "full_band": 2}
    yield "128x96 coarse factor 2", lambda: _model(small, (300.0, 900.0), {"coarse_factor": 2})
    yield "128x96 coarse factor 2 dense", lambda: _model(small, (300.0, 900.0), {"coarse_factor": 2, "dense": True})
    yield "256x192 pyramid", lambda: _model(thesis_setup1().downscaled(4), (400.0, 800.0), pyramid)


def graph_digest(path: str | Path) -> dict:
    """An exported graph, node for node, independent of tensor and node names (which follow module paths) and of
    the order of independent nodes: every tensor is named by a hash of the node that makes it (op type, domain,
    attributes with their values) and of that node's input tensors, recursively (a Merkle DAG; initializers by
    their values); the digest is the multiset of node hashes and the graph outputs' hashes."""
    import onnx
    from onnx import numpy_helper

    graph = onnx.load(str(path)).graph
    known: dict[str, str] = {x.name: f"input:{i}" for i, x in enumerate(graph.input)}
    for t in graph.initializer:
        known[t.name] = "init:" + hashlib.sha256(numpy_helper.to_array(t).tobytes()).hexdigest()
    known[""] = "none"

    def attribute(a) -> str:
        if a.type == onnx.AttributeProto.TENSOR:
            return a.name + "=" + hashlib.sha256(numpy_helper.to_array(a.t).tobytes()).hexdigest()
        if a.type == onnx.AttributeProto.GRAPH:
            return a.name + "=graph"
        return a.name + "=" + repr(onnx.helper.get_attribute_value(a))

    pending, node_hashes, ops = list(graph.node), [], {}
    while pending:  # exported graphs are topologically sorted; the loop tolerates any order
        waiting = []
        for node in pending:
            if not all(n in known for n in node.input):
                waiting.append(node)
                continue
            record = repr((node.op_type, node.domain, sorted(attribute(a) for a in node.attribute),
                           [known[n] for n in node.input]))
            digest = hashlib.sha256(record.encode()).hexdigest()
            node_hashes.append(digest)
            for i, name in enumerate(node.output):
                known[name] = f"{digest}:{i}"
            ops[node.op_type] = ops.get(node.op_type, 0) + 1
        if len(waiting) == len(pending):
            raise ValueError("the graph has a node whose inputs are never produced")
        pending = waiting
    whole = hashlib.sha256(repr((sorted(node_hashes), [known[o.name] for o in graph.output])).encode())
    return {"nodes": len(graph.node), "sha256": whole.hexdigest(), "ops": dict(sorted(ops.items()))}


def compute_graphs(tmp: Path) -> dict[str, dict]:
    from prismstereo.export import export_onnx

    out = {}
    with torch_threads(1):
        for i, (name, model) in enumerate(graph_cases()):
            path = export_onnx(model().eval(), tmp / f"graph{i}.onnx")
            out[name] = graph_digest(path)
    return out


def compute() -> dict[str, dict]:
    torch.manual_seed(0)
    out = {}
    with torch.inference_mode(), torch_threads(1):
        for name, model, capture in cases():
            out[name] = describe(model().eval()(capture()))
    return out


def host() -> str:
    """This host's key in the files: the CPU's model name and the torch build (what sets the float rounding)."""
    name = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                name = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{name} | torch {torch.__version__}"


def within_rounding(stored: dict, now: dict) -> list[str]:
    """Where an output entry (one case's fields, or one graph) computed on another host differs by more than float
    rounding: shapes, dtypes and node / operator counts exactly, counts of valid and finite values to 1e-4
    (at least 2), sums to 1e-5 relative."""
    problems = []
    if "nodes" in stored:  # a graph
        return [] if (stored["nodes"], stored["ops"]) == (now["nodes"], now["ops"]) else ["nodes or operators"]
    for field, a in stored.items():
        b = now[field]
        if (a["shape"], a["dtype"]) != (b["shape"], b["dtype"]):
            problems.append(f"{field}: shape or dtype")
        for key in ("count", "finite"):
            if key in a and abs(a[key] - b[key]) > max(2, 1e-4 * a[key]):
                problems.append(f"{field}: {key} {a[key]} -> {b[key]}")
        if "sum" in a and abs(a["sum"] - b["sum"]) > 1e-5 * max(1.0, abs(a["sum"])):
            problems.append(f"{field}: sum {a['sum']} -> {b['sum']}")
    return problems


def verdict(stored: dict[str, dict], name: str, now: dict) -> list[str]:
    """[] when ``now`` (an output entry of case or graph ``name``) is bitwise one stored host's, or, on a host that
    has no entry, within float rounding of every stored one; else what differs."""
    entries = {key: cases[name] for key, cases in stored.items() if name in cases}
    if not entries:
        return ["not stored"]
    if any(entry == now for entry in entries.values()):
        return []
    if host() in entries:
        return [f"not bitwise this host's ({host()})"]
    return [f"{key}: {problem}" for key, entry in entries.items() for problem in within_rounding(entry, now)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--check", action="store_true", help="compare with the stored files instead of writing them")
    parser.add_argument("--add-host", action="store_true", help="add this host's entry, keep the other hosts'")
    args = parser.parse_args()
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        graphs = compute_graphs(Path(tmp))
    now = compute()
    if not args.check:
        for path, fresh in ((PATH, now), (GRAPHS, graphs)):
            stored = json.loads(path.read_text()) if args.add_host and path.exists() else {}
            stored[host()] = fresh
            path.write_text(json.dumps(stored, indent=1, sort_keys=True) + "\n")
        print(f"wrote this host's entry ({host()}) to {PATH} ({len(now)} cases) and {GRAPHS} ({len(graphs)} graphs)")
        return
    bad = 0
    for path, fresh in ((PATH, now), (GRAPHS, graphs)):
        stored = json.loads(path.read_text())
        names = sorted({name for cases in stored.values() for name in cases} | set(fresh))
        for name in names:
            problems = verdict(stored, name, fresh[name]) if name in fresh else ["no longer a case"]
            if problems:
                bad += 1
                print(f"differs: {name}: " + "; ".join(problems))
        print(f"{path.name}: {len(names)} entries, hosts: {', '.join(stored)}")
    print(f"{bad} differ")
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
