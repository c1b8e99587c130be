"""``prismstereo depth --backend onnx`` on remembered graphs in a process where torch cannot be imported: a capture,
a folder of frames tracked by the temporal graph, and a video, each written bit for bit as the first (torch) run
wrote it."""

import re
import subprocess
import sys

import cv2
import numpy as np
import pytest

from prismstereo import thesis_setup1
from prismstereo.cli import main
from prismstereo.io import write_image

pytestmark = pytest.mark.usefixtures("one_thread")

DEPTHS = (500.0, 504.0, 508.0, 512.0)  # a plane moving slowly: frames after the first are tracked
FLAGS = ["--z-range", "400", "700", "--downsample", "2", "--full-band", "2", "--backend", "onnx"]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A rig file, one capture, its four frames as PNGs and as an MJPG video."""
    from prismstereo import synthetic as syn

    folder = tmp_path_factory.mktemp("without_torch")
    rig = thesis_setup1().downscaled(8)
    rig.to_json(folder / "small.json")
    scenes = [syn.fronto_parallel_plane(rig, z, seed=3) for z in DEPTHS]
    cap = syn.render(rig, scenes, syn.ImageFormation(supersample=1, noise_sigma=1 / 255, seed=1))
    (folder / "frames").mkdir()
    video = cv2.VideoWriter(str(folder / "clip.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 5.0,
                            (rig.image_width, rig.image_height))
    for k, image in enumerate(cap.image):
        write_image(folder / "frames" / f"f{k:03d}.png", image, bits=8)
        video.write(cv2.cvtColor((image[0].numpy() * 255).round().astype(np.uint8), cv2.COLOR_GRAY2BGR))
    video.release()
    write_image(folder / "one.png", cap.image[2], bits=16)
    return folder


def _depth(folder, source, out, *extra):
    return ["depth", str(folder / source), "--rig", str(folder / "small.json"), "--out", str(out), *FLAGS, *extra]


def test_remembered_graphs_run_without_torch(inputs, tmp_path, capsys):
    """The first runs (this process, torch) export and remember the request; the same commands in a process whose
    ``import torch`` fails run the remembered graphs through the torch-free pipeline and write the same bits; the
    frames are tracked (fewer key frames than frames)."""
    first = tmp_path / "first"
    assert main(_depth(inputs, "frames", first / "frames")) == 0
    assert main(_depth(inputs, "one.png", first / "one.npy")) == 0
    capsys.readouterr()
    again = tmp_path / "again"
    commands = [_depth(inputs, "frames", again / "frames"), _depth(inputs, "one.png", again / "one.npy"),
                _depth(inputs, "clip.avi", again / "clip", "--format", "png")]
    code = ("import sys\nsys.modules['torch'] = None  # import torch raises ImportError\n"
            "from prismstereo.cli import main\n"
            f"codes = [main(args) for args in {commands!r}]\n"
            "assert 'torch' not in sys.modules or sys.modules['torch'] is None\n"
            "print('codes', codes)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert "codes [0, 0, 0]" in run.stdout and run.stdout.count("backend onnx (without torch)") == 3, run.stdout
    keys = [int(n) for n in re.findall(r"(\d+) key frames", run.stdout)]
    assert len(keys) == 2 and all(1 <= k < len(DEPTHS) for k in keys), run.stdout
    for name in [f"frames/f{k:03d}.npy" for k in range(len(DEPTHS))] + ["one.npy"]:
        np.testing.assert_array_equal(np.load(again / name), np.load(first / name), err_msg=name)
    assert len(list((again / "clip").glob("clip_*_preview.png"))) == len(DEPTHS)


def test_a_request_not_remembered_builds_the_model(inputs, tmp_path, capsys):
    """Other flags are another request: the command takes the torch path (and remembers it)."""
    assert main(_depth(inputs, "one.png", tmp_path / "a.npy", "--band-edges", "reject")) == 0
    assert "(without torch)" not in capsys.readouterr().out


def test_deployed_graph_files_run_without_torch(inputs, tmp_path, capsys):
    """``depth --graph FILE --temporal-graph FILE``: exported files (no cache, no rig file) in a process where
    ``import torch`` fails, the same depth as the model's own ONNX run; model flags and torch-only outputs refused."""
    from prismstereo.classical import TemporalOptions
    from prismstereo.export import export_onnx
    from prismstereo.geometry.rig import BiPrismRig
    from prismstereo.models import build_model

    rig = BiPrismRig.from_json(inputs / "small.json")
    model = build_model(rig, "classical", (400.0, 700.0), {"downsample": 2, "full_band": 2})
    graph = export_onnx(model, tmp_path / "depth.onnx")
    temporal = export_onnx(model, tmp_path / "temporal.onnx", temporal=TemporalOptions())
    first = tmp_path / "first"
    assert main(_depth(inputs, "frames", first)) == 0  # the same model's request through the cache
    capsys.readouterr()
    common = ["--graph", str(graph), "--temporal-graph", str(temporal)]
    args = [["depth", str(inputs / "frames"), "--out", str(tmp_path / "again"), *common],
            ["depth", str(inputs / "one.png"), "--out", str(tmp_path / "one.npy"), "--graph", str(graph)]]
    code = ("import sys\nsys.modules['torch'] = None\nfrom prismstereo.cli import main\n"
            f"print('codes', [main(a) for a in {args!r}])")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and "codes [0, 0]" in run.stdout, run.stderr
    assert "(the graph's), depth.onnx" in run.stdout and "backend onnx (without torch)" in run.stdout
    assert re.search(r"\b[1-3] key frames", run.stdout), run.stdout
    for k in range(len(DEPTHS)):
        name = f"f{k:03d}.npy"
        np.testing.assert_array_equal(np.load(tmp_path / "again" / name), np.load(first / name), err_msg=name)
    for extra, message in ((["--rig", "small.json"], "--rig choose a model to build"),
                           (["--z-range", "400", "700"], "--z-range choose a model to build"),
                           (["--ply"], "--ply and --ray need it"),
                           (["--backend", "torch"], "not with --backend torch"),
                           (["--temporal-binning", "1"], "a temporal graph's band was placed when it was exported")):
        assert main(["depth", str(inputs / "one.png"), "--out", str(tmp_path / "x.npy"), "--graph", str(graph),
                     *extra]) == 2
        assert message in capsys.readouterr().err
    assert main(["depth", str(inputs / "one.png"), "--out", str(tmp_path / "x.npy"), "--temporal-graph",
                 str(temporal)]) == 2
    assert "--temporal-graph goes with --graph" in capsys.readouterr().err
    assert main(["depth", str(inputs / "one.png"), "--out", str(tmp_path / "x.npy")]) == 2
    assert "required: --rig (or --graph)" in capsys.readouterr().err
