"""Long jobs (``prismstereo.jobs`` and ``prismstereo depth`` on many inputs): planning, worker processes, failures,
resuming, whole files only."""

import os

import cv2
import numpy as np
import pytest
import torch

from prismstereo import PrismStereo, PrismStereoError, thesis_setup1
from prismstereo.cli import main
from prismstereo.io import read_depth, write_image
from prismstereo.jobs import (
    Pipeline,
    PlanError,
    Selection,
    WorkerProcesses,
    WriteOptions,
    check_inputs,
    plan,
    run,
)
from prismstereo.predictor import Predictor

pytestmark = pytest.mark.usefixtures("one_thread")

Z_RANGE = ("--z-range", "400", "700")


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A small rig, three captures of planes (one RGB), a 4-frame video, and a file that is not an image."""
    from prismstereo import synthetic as syn

    folder = tmp_path_factory.mktemp("jobs")
    rig = thesis_setup1().downscaled(8)
    rig.to_json(folder / "small.json")
    scenes = [syn.fronto_parallel_plane(rig, z, seed=k) for k, z in enumerate((480.0, 520.0, 560.0, 600.0))]
    cap = syn.render(rig, scenes, syn.ImageFormation(supersample=2, channels=3, noise_sigma=1 / 255, seed=1))
    for k in range(3):
        write_image(folder / f"cap{k}.png", cap.image[k, :1] if k else cap.image[k], bits=8)
    writer = cv2.VideoWriter(str(folder / "clip.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 5.0,
                             (rig.image_width, rig.image_height))
    for image in cap.image:
        grey = (image[0].numpy() * 255).round().astype(np.uint8)
        writer.write(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR))
    writer.release()
    (folder / "junk.png").write_bytes(b"not an image")
    return folder


def _sources(inputs):
    return [inputs / "cap0.png", inputs / "clip.avi", inputs / "junk.png", inputs / "cap1.png", inputs / "cap2.png"]


def _depth(inputs, *args):
    return main(["depth", *[str(a) for a in args], "--rig", str(inputs / "small.json"), *Z_RANGE])


def _files(folder):
    return sorted(p.name for p in folder.iterdir())


def test_check_inputs_reads_each_first_image_before_any_model(inputs, tmp_path):
    """Each capture decoded and sized, each sequence's first frame to process read; the others keep no error."""
    (tmp_path / "empty.png").write_bytes(b"")
    write_image(tmp_path / "small.png", torch.zeros(1, 48, 64))
    frames = tmp_path / "frames"
    frames.mkdir()
    (frames / "f0.png").write_bytes(b"broken")
    sources = [inputs / "cap0.png", inputs / "clip.avi", inputs / "junk.png", tmp_path / "empty.png",
               tmp_path / "small.png", frames, inputs / "missing.png"]
    tasks = check_inputs(plan(sources, tmp_path / "o", WriteOptions()), (96, 128))
    errors = [t.error for t in tasks]
    assert errors[:2] == [None, None] and "cannot decode image" in errors[2] and "cannot decode image" in errors[3]
    assert errors[4] == f"image {tmp_path / 'small.png'} is 64x48 px but the rig's sensor is 128x96 px"
    assert "cannot read frame 0" in errors[5] and errors[6] == f"image not found: {inputs / 'missing.png'}"
    # a sequence resumed at a later frame reads that one; a task with nothing left reads nothing
    resumed = plan([inputs / "clip.avi"], tmp_path / "o", WriteOptions())[0]
    assert check_inputs([resumed._replace(first=3)], (96, 128))[0].error is None
    assert check_inputs([resumed._replace(first=4)], (1, 1))[0].error is None


def test_plan_names_every_output_and_refuses_collisions(inputs, tmp_path):
    tasks = plan(_sources(inputs) + [inputs / "missing.png", inputs / "none.avi"], tmp_path / "o",
                 WriteOptions(format="png", ply=True), Selection(every=2))
    assert [len(t.outputs) for t in tasks] == [1, 2, 1, 1, 1, 1, 0]
    assert tasks[1].outputs[1] == (tmp_path / "o" / "clip_000001.png", tmp_path / "o" / "clip_000001_preview.png",
                                   tmp_path / "o" / "clip_000001.ply", None, tmp_path / "o" / "clip_000001.json")
    assert tasks[5].error == f"image not found: {inputs / 'missing.png'}" and "video not found" in tasks[6].error
    assert tasks[2].error is None  # an undecodable image fails when it is read, with the others still written
    with pytest.raises(PrismStereoError, match="would both write"):
        plan([inputs / "cap0.png", tmp_path / "cap0.png"], tmp_path / "o", WriteOptions())
    with pytest.raises(PlanError, match="out would overwrite the input image") as error:
        plan([inputs / "cap0.png"], inputs, WriteOptions(format="png"))
    assert error.value.naming({"out": "--out"}).startswith("--out would overwrite the input image")
    with pytest.raises(PrismStereoError, match="need a video, a directory or a glob"):
        plan([inputs / "cap0.png"], tmp_path, WriteOptions(), Selection(start=1))
    with pytest.raises(PlanError, match="preview_video needs a single video"):
        plan([inputs / "clip.avi", inputs / "clip.avi"], tmp_path, WriteOptions(preview_video=tmp_path / "p.mp4"))
    with pytest.raises(PrismStereoError, match="a video or sequence writes one file per frame"):
        plan([inputs / "clip.avi"], tmp_path / "d.npy", WriteOptions())
    with pytest.raises(PlanError, match="every must be an int >= 1, got 0") as error:
        plan([inputs / "clip.avi"], tmp_path, WriteOptions(), Selection(every=0))
    assert error.value.naming({"every": "--every"}) == "--every must be an int >= 1, got 0"
    with pytest.raises(PrismStereoError, match="workers must be an int >= 1"):
        WorkerProcesses(0)
    with pytest.raises(PrismStereoError, match="batch_size must be an int >= 1"):
        run(tasks, None, batch_size=0)


def test_workers_write_the_same_files_and_report_failures(inputs, tmp_path, capsys):
    """One process and two: the same files (depths equal, NaN where NaN), the undecodable input reported at the end
    with its reason and a non-zero exit, the others written."""
    for workers in (1, 2):
        code = _depth(inputs, *_sources(inputs), "--out", tmp_path / f"w{workers}", "--workers", workers, "--ply")
        out, err = capsys.readouterr()
        assert code == 1
        assert f"prismstereo: failed: {inputs / 'junk.png'}: cannot decode image" in err
        assert "5 inputs, 7 depth maps written" in out and "1 inputs failed" in out
    names = _files(tmp_path / "w1")
    # 7 depth maps, 7 point clouds and the 3 captures' previews (the video's frames are .npy: no preview)
    assert names == _files(tmp_path / "w2") and len(names) == 17 and "clip_000003.npy" in names
    assert "cap0_preview.png" in names and "clip_000000_preview.png" not in names
    assert not [n for n in names if "partial" in n]
    for name in names:
        if name.endswith(".npy"):
            a, b = (np.load(tmp_path / f"w{w}" / name) for w in (1, 2))
            np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
            np.testing.assert_allclose(a, b, rtol=1e-6, equal_nan=True)
    assert abs(np.nanmedian(np.load(tmp_path / "w1" / "cap2.npy")) / 560.0 - 1) < 0.02
    assert abs(np.nanmedian(np.load(tmp_path / "w1" / "clip_000003.npy")) / 600.0 - 1) < 0.02


def test_skip_existing_resumes_images_and_sequences(inputs, tmp_path, capsys):
    out = tmp_path / "o"
    sources = [inputs / "cap0.png", inputs / "clip.avi", inputs / "cap1.png"]
    assert _depth(inputs, *sources, "--out", out) == 0
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    (out / "cap1.npy").unlink()
    (out / "clip_000002.npy").unlink()  # frames 2 and 3 are computed again, from a key frame
    reference = np.load(out / "clip_000003.npy")
    (out / "clip_000003.npy").unlink()
    capsys.readouterr()
    assert _depth(inputs, *sources, "--out", out, "--skip-existing") == 0
    text = capsys.readouterr().out
    assert "3 depth maps to write from 2 of 3 inputs" in text and "3 skipped (already written)" in text
    assert "resumed at output 2" in text
    after = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    assert set(after) == set(before)
    assert sorted(n for n in after if after[n] != before[n]) == ["cap1.npy", "cap1_preview.png", "clip_000002.npy",
                                                                 "clip_000003.npy"]
    resumed = np.load(out / "clip_000003.npy")
    both = np.isfinite(resumed) & np.isfinite(reference)
    assert both.mean() > 0.5 and np.abs(resumed[both] / reference[both] - 1).max() < 0.01
    assert _depth(inputs, *sources, "--out", out, "--skip-existing") == 0
    assert "0 depth maps to write from 0 of 3 inputs" in capsys.readouterr().out


def test_a_failed_write_leaves_whole_files_only(inputs, tmp_path, monkeypatch):
    """The writer fails on the third frame of the video: the sequence stops there, its first two files are whole,
    no partial file is left, the captures after it are written and the job reports the failure."""
    rig = thesis_setup1().downscaled(8)
    model = PrismStereo(rig, (400.0, 700.0))
    tasks = plan([inputs / "clip.avi", inputs / "cap1.png"], tmp_path, WriteOptions())
    real = np.save

    def failing(path, data, *args, **kwargs):
        if "clip_000002" in str(path):
            with open(path, "wb") as fh:  # half a file, then the disk is full
                fh.write(b"\x93NUMPY")
            raise OSError(28, "No space left on device")
        return real(path, data, *args, **kwargs)

    monkeypatch.setattr(np, "save", failing)
    summary = run(tasks, Pipeline(Predictor(model)), progress=False, report=lambda r: None)
    assert [r.written for r in summary.reports] == [2, 1]
    assert "No space left on device" in summary.reports[0].error and summary.reports[1].error is None
    assert _files(tmp_path) == ["cap1.npy", "cap1_preview.png", "clip_000000.npy", "clip_000001.npy"]
    assert read_depth(tmp_path / "clip_000001.npy").shape == (rig.image_height, rig.reference_width)
    assert "1 inputs failed" in summary.describe()


def test_a_cached_graph_runs_alone_in_workers(inputs, tmp_path, monkeypatch, capsys):
    """The ONNX backend's second run of a request loads the cached graph without a torch model, in the worker
    processes too, and writes what the first run wrote."""
    monkeypatch.setenv("PRISMSTEREO_CACHE", str(tmp_path / "cache"))
    captures = [inputs / "cap0.png", inputs / "cap1.png", inputs / "cap2.png"]
    assert _depth(inputs, *captures, "--out", tmp_path / "a", "--backend", "onnx") == 0
    assert "(cached graph)" not in capsys.readouterr().out
    assert _depth(inputs, *captures, "--out", tmp_path / "b", "--backend", "onnx", "--workers", 2) == 0
    assert "(cached graph), backend onnx, 2 worker processes" in capsys.readouterr().out
    for name in ("cap0.npy", "cap1.npy", "cap2.npy"):
        np.testing.assert_array_equal(np.load(tmp_path / "a" / name), np.load(tmp_path / "b" / name))


@pytest.fixture(scope="module")
def local_ray():
    """A local Ray instance of 2 CPUs for the module's Ray tests (each starts its own actors)."""
    ray = pytest.importorskip("ray")  # in the dev install: never skipped there
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield ray
    ray.shutdown()


def _ray_workers() -> list[int]:
    pids = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/cmdline", "rb") as fh:
                    if fh.read().startswith(b"ray::_Worker"):
                        pids.append(int(entry))
            except OSError:
                continue
    return pids


def test_ray_writes_the_same_files_and_survives_a_dead_worker(inputs, tmp_path, local_ray, capsys):
    """``--ray`` on a local instance: the files of the single-process run (float rounding: one thread per actor),
    the failing input reported; one actor killed after the first report is replaced and its work retried,
    and no temporary file is left."""
    import signal

    from prismstereo.jobs import ray_executor

    sources = _sources(inputs)
    assert _depth(inputs, *sources, "--out", tmp_path / "one") == 1
    killed = []
    real = ray_executor._run_actors

    def kill_after_first(ray, units, pipeline, batch_size, deliver, tick):
        def deliver_and_kill(i, rep):
            deliver(i, rep)
            if not killed and (pids := _ray_workers()):
                os.kill(pids[0], signal.SIGKILL)
                killed.append(pids[0])
        return real(ray, units, pipeline, batch_size, deliver_and_kill, tick)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(ray_executor, "_run_actors", kill_after_first)
        assert _depth(inputs, *sources, "--out", tmp_path / "ray", "--ray", "--ply") == 1
    out, err = capsys.readouterr()
    assert killed and "on Ray (local)" in out and f"failed: {inputs / 'junk.png'}: cannot decode image" in err
    names = _files(tmp_path / "ray")
    assert len(names) == 17 and not [n for n in names if "partial" in n]
    for name in [n for n in _files(tmp_path / "one") if n.endswith(".npy")]:
        a, b = np.load(tmp_path / "one" / name), np.load(tmp_path / "ray" / name)
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
        np.testing.assert_allclose(a, b, rtol=1e-5, equal_nan=True)


def test_depth_mapper_maps_the_model_over_batches_as_ray_data_hands_them(inputs):
    """``DepthMapper``, what ``Dataset.map_batches(DepthMapper, fn_constructor_kwargs={"pipeline": ...})`` calls: built
    from an unpickled pipeline (as Ray ships it), called on dict batches of uint8 grey rows and of an object
    column of RGB rows (``read_images`` of mixed files): the depth of each row's image as the pipeline computes it
    (NaN where invalid), the other columns passed through. (Ray Data's own scheduling of it is Ray's.)"""
    import pickle

    from prismstereo.io import read_image
    from prismstereo.jobs.ray_executor import DepthMapper

    rig = thesis_setup1().downscaled(8)
    pipeline = Pipeline(Predictor(PrismStereo(rig, (400.0, 700.0))))
    mapper = DepthMapper(pickle.loads(pickle.dumps(pipeline)))
    images = [(read_image(inputs / f"cap{k}.png")[:1, :, :].numpy()[0] * 255).round().astype(np.uint8)
              for k in range(3)]
    rgb = np.empty(2, dtype=object)
    rgb[:] = [np.repeat(im[..., None], 3, -1) for im in images[:2]]
    for batch in ({"name": np.array(["cap0", "cap1", "cap2"]), "image": np.stack(images)},
                  {"name": np.array(["cap0", "cap1"]), "image": rgb}):
        out = mapper(batch)
        assert list(out["name"]) == list(batch["name"]) and out["depth"].dtype == np.float32
        for k in range(len(batch["name"])):
            res = pipeline.depth(torch.from_numpy(images[k]).float()[None, None] / 255)
            expected = torch.where(res.valid, res.depth, torch.full_like(res.depth, float("nan")))[0, 0].numpy()
            assert out["depth"][k].shape == (rig.image_height, rig.reference_width)
            np.testing.assert_allclose(out["depth"][k], expected, rtol=1e-5, equal_nan=True)
            np.testing.assert_allclose(out["confidence"][k], res.confidence[0, 0].numpy(), atol=1e-5)
    with pytest.raises(PrismStereoError, match="rig's sensor is 128x96 px"):
        mapper({"image": np.zeros((1, 10, 10), np.uint8)})


def test_planning_a_job_needs_no_torch(tmp_path):
    """The plan, its checks of captures and the run's summary run without torch."""
    import subprocess
    import sys

    cv2.imwrite(str(tmp_path / "b.png"), np.zeros((6, 8), np.uint8))
    code = ("import sys; from pathlib import Path\n"
            "from prismstereo.jobs import plan, run, WriteOptions, JobSummary, check_inputs\n"
            f"tasks = plan([r'{tmp_path / 'a.png'}'], Path(r'{tmp_path / 'o'}'), WriteOptions(format='png'))\n"
            f"checked = check_inputs(plan([r'{tmp_path / 'b.png'}'], Path(r'{tmp_path / 'o'}'), WriteOptions()),"
            " (6, 8))\n"
            "assert checked[0].error is None\n"
            "print(tasks[0].outputs[0].depth.name, tasks[0].error, 'torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["a.png", "image", "not", "found:", str(tmp_path / "a.png"), "False"]
