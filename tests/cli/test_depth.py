"""``prismstereo depth`` on a 128 x 96 version of setup 1 (rendered fronto-parallel planes)."""

import json
import os
import re
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest
import torch

from prismstereo import thesis_setup1
from prismstereo.cli import main
from prismstereo.io import read_depth, read_depth_png, read_image, write_image

NEAR, FAR = 240.0, 525.0  # mm: the near plane fits the 16-bit PNG's 255.996 mm, the far one does not


pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A small rig file, an 8-bit grey capture of a plane at FAR and a 16-bit RGB one at NEAR."""
    from prismstereo import synthetic as syn

    folder = tmp_path_factory.mktemp("depth_cli")
    rig = thesis_setup1().downscaled(8)
    rig.to_json(folder / "small.json")
    planes = [syn.fronto_parallel_plane(rig, FAR, seed=3), syn.fronto_parallel_plane(rig, NEAR, seed=4, channels=3)]
    cap = syn.render(rig, planes, syn.ImageFormation(supersample=2, channels=3, noise_sigma=1 / 255, seed=1))
    write_image(folder / "far.png", cap.image[0, :1], bits=8)
    write_image(folder / "near.png", cap.image[1], bits=16)
    return folder


def _run(scene, *args):
    return main(["depth", *[str(a) for a in args], "--rig", str(scene / "small.json")])


def test_npy_of_a_plane(scene, tmp_path, capsys):
    out = tmp_path / "far.npy"
    assert _run(scene, scene / "far.png", "--out", out) == 0
    text = capsys.readouterr().out
    assert "depth range 222.1-1332.6 mm (default for this rig)" in text and f"wrote {out}" in text
    depth = np.load(out)
    assert depth.shape == (96, 64) and depth.dtype == np.float32
    assert np.isnan(depth).any() and np.isfinite(depth).mean() > 0.5
    assert abs(np.nanmedian(depth) / FAR - 1) < 0.02
    # its one line: the valid share and the depth range; a preview beside the .npy (none with --no-preview)
    ok = depth[np.isfinite(depth)]
    assert re.search(rf"wrote {re.escape(str(out))}: \d+\.\d% of reference pixels valid, depth "
                     rf"{ok.min():.1f}-{ok.max():.1f} mm \(median [\d.]+\), preview far_preview.png", text), text
    assert read_image(tmp_path / "far_preview.png").shape[0] == 3
    assert _run(scene, scene / "far.png", "--out", tmp_path / "o.tiff", "--no-preview") == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["far.npy", "far_preview.png", "o.tiff"]


def test_png_round_trip_preview_and_ply(scene, tmp_path, capsys):
    npy, png = tmp_path / "near.npy", tmp_path / "near.png"
    assert _run(scene, scene / "near.png", "--out", npy, "--z-range", 200, 400, "--ply") == 0
    assert _run(scene, scene / "near.png", "--out", png, "--z-range", 200, 400) == 0
    assert "depth range 200.0-400.0 mm (--z-range)" in capsys.readouterr().out
    depth = np.load(npy)
    assert abs(np.nanmedian(depth) / NEAR - 1) < 0.02
    import cv2

    raw = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.shape == (96, 64)
    scale = json.loads((tmp_path / "near.json").read_text())["depth_scale"]  # 256 where every depth fits
    assert scale == (256.0 if np.nanmax(depth) * 256 <= 65535 else 128.0)
    expected = np.where(np.isnan(depth), 0, np.clip(np.round(depth.astype(np.float64) * scale), 1, 65535))
    assert (raw == expected).all()  # the same model run, written as round(mm x scale), 0 invalid
    back = read_depth(png).numpy()
    ok = np.isfinite(depth)
    assert ok.mean() > 0.2 and np.abs(back[ok] - depth[ok]).max() <= 0.5 / scale + 1e-4
    preview = read_image(tmp_path / "near_preview.png")
    hatched = preview[:, :, :64][:, torch.from_numpy(np.isnan(depth))]  # no depth: grey stripes
    assert preview.shape[:2] == (3, 96) and preview.shape[2] > 64 and (hatched[0] == hatched[2]).all()  # + the bar
    from prismstereo.depth import read_ply

    cloud = read_ply(tmp_path / "near.ply")  # next to near.npy
    assert cloud.points.shape[0] == np.isfinite(depth).sum() and cloud.colors.shape == cloud.points.shape
    np.testing.assert_allclose(np.sort(cloud.points[:, 2].numpy()), np.sort(depth[np.isfinite(depth)]), rtol=1e-6)
    image = read_image(scene / "near.png")[:, :, :64]  # colours of the reference half
    first = np.argwhere(np.isfinite(depth))[0]
    assert cloud.colors[0].tolist() == (image[:, first[0], first[1]] * 255).round().to(torch.uint8).tolist()


def test_downsample_runs_on_binned_pixels_and_writes_the_full_grid(scene, tmp_path, capsys):
    out = tmp_path / "far.npy"
    assert _run(scene, scene / "far.png", "--out", out, "--downsample", "2") == 0
    assert "hypotheses in one level, on 2x2-binned pixels" in capsys.readouterr().out
    depth = np.load(out)
    assert depth.shape == (96, 64) and np.isfinite(depth).mean() > 0.4
    assert abs(np.nanmedian(depth) / FAR - 1) < 0.02
    assert (np.isnan(depth[::2, ::2]) == np.isnan(depth[1::2, 1::2])).all()  # 2 x 2 blocks share their values


def test_full_band_refines_the_binned_depth_at_full_resolution(scene, tmp_path, capsys):
    out = tmp_path / "far.npy"
    assert _run(scene, scene / "far.png", "--out", out, "--downsample", "2", "--full-band", "2") == 0
    assert ", then a full-resolution band +-2 of " in capsys.readouterr().out
    depth = np.load(out)
    assert depth.shape == (96, 64) and np.isfinite(depth).mean() > 0.4
    assert abs(np.nanmedian(depth) / FAR - 1) < 0.02
    both = np.isfinite(depth[::2, ::2]) & np.isfinite(depth[1::2, 1::2])
    assert (depth[::2, ::2] != depth[1::2, 1::2])[both].mean() > 0.9  # no longer the block's value


def test_band_edges_clamp_reaches_the_model(scene, tmp_path, capsys):
    out = tmp_path / "far.npy"
    args = ("--out", out, "--downsample", "2", "--full-band", "1")
    assert _run(scene, scene / "far.png", *args, "--band-edges", "clamp") == 0
    assert "band +-1 of " in (text := capsys.readouterr().out) and "band edges clamped" in text
    clamped = np.isfinite(np.load(out)).sum()
    assert _run(scene, scene / "far.png", *args, "--band-edges", "reject") == 0
    assert "band edges clamped" not in capsys.readouterr().out
    assert clamped > np.isfinite(np.load(out)).sum()  # the band's edge pixels (more than the z-buffer removes)
    with pytest.raises(SystemExit):
        _run(scene, scene / "far.png", *args, "--band-edges", "widen")


def test_dense_writes_every_covered_pixel_and_its_confidence(scene, tmp_path, capsys):
    """--dense: a depth for every pixel of the common field of view, the confidence beside it (0 exactly where
    there is no depth); more pixels than the valid ones, the same depths where both have one."""
    plain, dense = tmp_path / "plain.npy", tmp_path / "dense.npy"
    args = ("--z-range", 400, 700, "--downsample", "2", "--full-band", "1")
    # the valid pixels of a band that rejects its edges (the default's clamped band keeps all of this easy plane)
    assert _run(scene, scene / "far.png", "--out", plain, *args, "--band-edges", "reject") == 0
    assert _run(scene, scene / "far.png", "--out", dense, *args, "--dense") == 0
    text = capsys.readouterr().out
    assert "with a depth (dense)" in text and "confidence dense_confidence.npy" in text
    d0, d1 = np.load(plain), np.load(dense)
    confidence = np.load(tmp_path / "dense_confidence.npy")
    assert confidence.shape == d1.shape and confidence.dtype == np.float32
    assert np.array_equal(np.isfinite(d1), confidence > 0) and confidence.max() <= 1.0
    assert np.isfinite(d1).sum() > np.isfinite(d0).sum()
    both = np.isfinite(d0) & np.isfinite(d1)
    assert both.mean() > 0.3 and np.median(np.abs(d0[both] / d1[both] - 1)) < 1e-4


def test_ply_carries_confidence_and_a_world_frame(scene, tmp_path, capsys):
    import json as _json

    from prismstereo.depth import read_ply

    assert _run(scene, scene / "far.png", "--out", tmp_path / "cam.npy", "--ply") == 0
    pose = [[0.0, -1.0, 0.0, 5.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, -100.0], [0.0, 0.0, 0.0, 1.0]]
    (tmp_path / "pose.json").write_text(_json.dumps({"camera_to_world": pose}))
    assert _run(scene, scene / "far.png", "--out", tmp_path / "world.npy", "--ply", "--camera-to-world",
                tmp_path / "pose.json") == 0
    cam, world = read_ply(tmp_path / "cam.ply"), read_ply(tmp_path / "world.ply")
    assert cam.confidence is not None and bool((cam.confidence >= 0.5).all())  # valid points: confident ones
    p = torch.tensor(pose, dtype=torch.float64)
    torch.testing.assert_close(world.points.double(), cam.points.double() @ p[:3, :3].T + p[:3, 3], atol=1e-3,
                               rtol=1e-6)
    (tmp_path / "bad.json").write_text(_json.dumps([[2.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]))
    capsys.readouterr()
    assert _run(scene, scene / "far.png", "--out", tmp_path / "x.npy", "--ply", "--camera-to-world",
                tmp_path / "bad.json") == 2
    assert "is not a rigid transform" in capsys.readouterr().err
    assert _run(scene, scene / "far.png", "--out", tmp_path / "x.npy", "--camera-to-world", tmp_path / "pose.json") == 2
    assert "--camera-to-world transforms the --ply point clouds: add --ply" in capsys.readouterr().err


def test_dense_confidence_file_cannot_collide_with_another_output(scene, tmp_path, capsys):
    import shutil

    a, b = tmp_path / "scan.png", tmp_path / "scan_confidence.png"
    shutil.copy(scene / "far.png", a)
    shutil.copy(scene / "far.png", b)
    args = ("--out", tmp_path / "out", "--downsample", "2", "--full-band", "1")
    assert _run(scene, a, b, *args, "--dense") == 2
    assert "would both write" in capsys.readouterr().err
    assert _run(scene, a, b, *args) == 0  # without --dense no confidence file, no collision


def test_png_scale_automatic_or_clipping_with_a_warning(scene, tmp_path, capsys):
    """Depths beyond 256 mm: an explicit x256 clips with a warning; the default picks a scale that fits, stores
    it in the PNG and its sidecar, says so, and read_depth finds it; float TIFF keeps the depth exactly."""
    assert _run(scene, scene / "far.png", "--out", tmp_path / "far.png", "--png-scale", 256) == 0
    assert "clipped to 65535 (see --png-scale)" in capsys.readouterr().out
    assert _run(scene, scene / "far.png", "--out", tmp_path / "auto.png") == 0
    out = capsys.readouterr().out
    assert "warning" not in out and "levels/mm (stored in the PNG and auto.json)" in out
    assert abs(np.nanmedian(read_depth(tmp_path / "auto.png").numpy()) / FAR - 1) < 0.02
    scale = json.loads((tmp_path / "auto.json").read_text())["depth_scale"]
    assert f"{scale:g} levels/mm" in out
    assert abs(np.nanmedian(read_depth_png(tmp_path / "auto.png", scale).numpy()) / FAR - 1) < 0.02
    assert _run(scene, scene / "far.png", "--out", tmp_path / "far.tiff") == 0
    assert _run(scene, scene / "far.png", "--out", tmp_path / "far.npy") == 0
    tiff, npy = read_depth(tmp_path / "far.tiff").numpy(), np.load(tmp_path / "far.npy")
    np.testing.assert_array_equal(tiff, npy)


def test_directory_of_two_images_batched_with_ply(scene, tmp_path, capsys):
    out = tmp_path / "results"
    assert _run(scene, scene / "far.png", scene / "near.png", "--out", out, "--batch-size", "2", "--ply",
                "--hypotheses", "48") == 0
    assert "48 hypotheses" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["far.npy", "far.ply", "far_preview.png", "near.npy", "near.ply",
                                                     "near_preview.png"]
    assert abs(np.nanmedian(np.load(out / "far.npy")) / FAR - 1) < 0.02
    assert abs(np.nanmedian(np.load(out / "near.npy")) / NEAR - 1) < 0.02
    from prismstereo.depth import read_ply

    assert read_ply(out / "far.ply").colors.shape[1] == 3
    assert _run(scene, scene / "far.png", scene / "near.png", "--out", out, "--format", "png") == 0
    assert {"far.png", "far_preview.png", "far.json", "near.png", "near_preview.png"} <= {p.name for p in out.iterdir()}


@pytest.mark.parametrize(
    "args,message",
    [
        (["{junk}", "--out", "{tmp}/d.npy"], "cannot decode image"),
        (["{empty}", "--out", "{tmp}/d.npy"], "cannot decode image"),
        (["{truncated}", "--out", "{tmp}/d.npy"], "cannot decode image"),
        (["{junk}", "{empty}", "--out", "{tmp}/o"], "none of the 2 inputs can be processed"),
        (["{tmp}/missing.png", "--out", "{tmp}/d.npy"], "image not found"),
        (["{small}", "--out", "{tmp}/d.npy"], "is 64x48 px but the rig's sensor is 128x96 px"),
        (["{far}", "--out", "{tmp}/d.npy", "--z-range", "100", "500"], "not beyond the prism's back plane"),
        (["{far}", "--out", "{tmp}/d.npy", "--z-range", "600", "400"], "must be greater than z_min"),
        (["{far}", "--out", "{far}"], "--out would overwrite the input image"),
        (["{far}", "--out", "{dir}", "--format", "png"], "--out would overwrite the input image"),
        (["{far}", "{far}", "--out", "{tmp}/d.npy"], "2 images: --out must be a directory"),
        (["{far}", "{tmp}/x/far.png", "--out", "{tmp}/o"], "would both write {tmp}/o/far.npy"),
        (["{far}", "{tmp}/far_preview.png", "--out", "{tmp}/o", "--format", "png"], "would both write"),
        (["{far}", "--out", "{tmp}/d.exr"], "--out must end in .npy, .png or .tiff (one image) or be a directory"),
        (["{far}", "--out", "{tmp}/d.npy", "--format", "png"], "--format png contradicts --out"),
        (["{far}", "--out", "{tmp}/d.npy", "--batch-size", "0"], "--batch-size must be >= 1"),
        (["{far}", "--out", "{tmp}/d.npy", "--hypotheses", "1"], "--hypotheses must be an int >= 2, got 1"),
        (["{far}", "--out", "{tmp}/d.npy", "--downsample", "0"], "--downsample must be an int >= 1, got 0"),
        (["{far}", "--out", "{tmp}/d.npy", "--full-band", "2"], "--full-band must be an int >= 0, and > 0 only"),
        (["{far}", "--out", "{tmp}/d.png", "--png-scale", "0"], "--png-scale must be a positive number"),
    ],
)
def test_errors(scene, tmp_path, capsys, monkeypatch, args, message):
    """Every bad input or flag fails with one line (after one per failed input), a bad input before the model is
    built."""
    from prismstereo.predictor import Predictor

    (tmp_path / "junk.png").write_bytes(b"not an image")
    (tmp_path / "empty.png").write_bytes(b"")
    (tmp_path / "truncated.png").write_bytes((scene / "far.png").read_bytes()[:300])
    write_image(tmp_path / "small.png", torch.rand(1, 48, 64))
    names = {"junk": tmp_path / "junk.png", "small": tmp_path / "small.png", "far": scene / "far.png",
             "dir": scene, "tmp": tmp_path, "empty": tmp_path / "empty.png", "truncated": tmp_path / "truncated.png"}
    if args[0] != "{far}":  # a bad input: found before the model is built
        monkeypatch.setattr(Predictor, "__init__", lambda *a, **k: pytest.fail("a model was built"))
    assert _run(scene, *[a.format(**names) for a in args]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert all(line.startswith("prismstereo: failed:") for line in lines[:-1]), lines  # no progress bar
    err = lines[-1]
    assert err.startswith("prismstereo: error:") and message.format(**names) in err
    assert (scene / "far.png").exists() and read_image(scene / "far.png").shape == (1, 96, 128)


def test_onnx_backend_matches_torch(scene, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("PRISMSTEREO_CACHE", str(tmp_path / "cache"))
    a, b = tmp_path / "torch.npy", tmp_path / "onnx.npy"
    assert _run(scene, scene / "far.png", "--out", a, "--z-range", 400, 700) == 0
    assert _run(scene, scene / "far.png", "--out", b, "--z-range", 400, 700, "--backend", "onnx") == 0
    assert "backend onnx" in capsys.readouterr().out
    assert len(list((tmp_path / "cache" / "onnx").glob("*.onnx"))) == 1  # exported once, cached
    # the same request again: the cached graph runs without a torch model being built
    from prismstereo.classical.model import PrismStereo

    monkeypatch.setattr(PrismStereo, "__init__", lambda *a, **k: pytest.fail("a model was built"))
    c = tmp_path / "cached.npy"
    assert _run(scene, scene / "far.png", "--out", c, "--z-range", 400, 700, "--backend", "onnx") == 0
    assert "(cached graph)" in capsys.readouterr().out
    np.testing.assert_array_equal(np.load(b), np.load(c))
    # a cached graph's run in a fresh process, on a colour capture, loads neither a torch model nor kornia
    code = ("import sys; from prismstereo.cli import main; rc = main(sys.argv[1:]); "
            "print('exit', rc, 'kornia' in sys.modules, 'prismstereo.classical.model' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", code, "depth", str(scene / "near.png"), "--rig",
                           str(scene / "small.json"), "--out", str(tmp_path / "near.npy"), "--z-range", "400", "700",
                           "--backend", "onnx"], capture_output=True, text=True,
                          env={**os.environ, "PRISMSTEREO_CACHE": str(tmp_path / "cache")})
    assert "(cached graph)" in proc.stdout and proc.stdout.splitlines()[-1] == "exit 0 False False", proc.stdout
    # `prismstereo export` of the same request copies the cached graph (another opset is another export)
    out = tmp_path / "exported.onnx"
    assert main(["export", "--rig", str(scene / "small.json"), "--out", str(out), "--z-range", "400", "700"]) == 0
    text = capsys.readouterr().out
    assert "(cached graph)" in text and "copied from the cache" in text, text
    assert out.read_bytes() == next((tmp_path / "cache" / "onnx").glob("*.onnx")).read_bytes()
    assert not list(tmp_path.glob(".*partial*"))
    with pytest.raises(pytest.fail.Exception, match="a model was built"):
        main(["export", "--rig", str(scene / "small.json"), "--out", str(out), "--z-range", "400", "700",
              "--opset", "17"])
    da, db = np.load(a), np.load(b)
    both = np.isfinite(da) & np.isfinite(db)
    assert both.mean() > 0.5 and (np.isfinite(da) == np.isfinite(db)).mean() >= 0.999
    assert np.abs(da[both] / db[both] - 1).max() <= 1e-4


def test_export_writes_a_loadable_model(scene, tmp_path, capsys):
    from prismstereo.export import OnnxDepth

    out = tmp_path / "m.onnx"
    assert main(["export", "--rig", str(scene / "small.json"), "--out", str(out), "--z-range", "400", "700",
                 "--hypotheses", "24", "--opset", "17"]) == 0
    text = capsys.readouterr().out
    assert f"wrote {out}" in text and "input (B, 1, 96, 128), 24 hypotheses over 400.0-700.0 mm" in text
    runner = OnnxDepth(out)
    assert runner.metadata["prismstereo.opset"] == "17" and runner.input_shape == (1, 96, 128)
    dense = tmp_path / "dense.onnx"
    assert main(["export", "--rig", str(scene / "small.json"), "--out", str(dense), "--z-range", "400", "700",
                 "--dense"]) == 2  # the small rig's default is a single level: no band to place everywhere
    assert "dense needs a coarse-to-fine model" in capsys.readouterr().err
    assert main(["export", "--rig", str(scene / "small.json"), "--out", str(dense), "--z-range", "400", "700",
                 "--dense", "--downsample", "2", "--full-band", "1"]) == 0
    assert json.loads(OnnxDepth(dense).metadata["prismstereo.config"])["config"]["validity"]["dense"] is True
    hybrid = tmp_path / "hybrid.onnx"  # the request of test_hybrid_model_from_the_cli[onnx]: one export for both
    assert main(["export", "--rig", str(scene / "small.json"), "--out", str(hybrid), "--z-range", "400", "900",
                 "--model", "hybrid"]) == 0
    assert json.loads(OnnxDepth(hybrid).metadata["prismstereo.config"])["model"] == "HybridStereo"
    assert main(["export", "--rig", str(scene / "small.json"), "--out", str(tmp_path / "m.txt")]) == 2
    assert "--out must end in .onnx" in capsys.readouterr().err
    assert main(["export", "--rig", str(scene / "small.json"), "--out", str(out), "--opset", "12"]) == 2
    assert "opset must be" in capsys.readouterr().err


def test_console_script_error_has_no_traceback(scene, tmp_path):
    write_image(tmp_path / "small.png", torch.rand(1, 48, 64))
    proc = subprocess.run([sys.executable, "-m", "prismstereo.cli", "depth", str(tmp_path / "small.png"), "--rig",
                           str(scene / "small.json"), "--out", str(tmp_path / "d.npy")], capture_output=True, text=True)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "the rig's sensor is 128x96 px" in proc.stderr


@pytest.mark.parametrize("backend", ["torch", "onnx"])
def test_learned_model_from_the_cli(scene, tmp_path, capsys, backend):
    """--model learned runs the shipped learned model (both backends); --weights takes another file; the classical
    model's options are refused with it."""
    out = tmp_path / "far.npy"
    assert _run(scene, scene / "far.png", "--out", out, "--model", "learned", "--z-range", 400, 900, "--backend",
                backend) == 0
    assert "learned model: " in capsys.readouterr().out
    depth = np.load(out)
    assert depth.shape == (96, 64) and abs(np.nanmedian(depth) / FAR - 1) < 0.05
    assert _run(scene, scene / "far.png", "--out", tmp_path / "x.npy", "--model", "learned", "--preset", "fast") == 2
    assert "--preset set the classical model's options, not --model learned's" in capsys.readouterr().err
    assert _run(scene, scene / "far.png", "--out", tmp_path / "x.npy", "--model", "learned", "--weights",
                tmp_path / "none.pt") == 2
    assert "none.pt" in capsys.readouterr().err


@pytest.mark.parametrize("backend", ["torch", "onnx"])
def test_hybrid_model_from_the_cli(scene, tmp_path, capsys, backend):
    """--model hybrid runs the shipped hybrid (both backends, a depth for every pixel with --dense), --weights takes
    another hybrid weights file; the classical model's options are refused with it."""
    out = tmp_path / "far.npy"
    assert _run(scene, scene / "far.png", "--out", out, "--z-range", 400, 900, "--backend", backend, "--dense",
                "--model", "hybrid") == 0
    assert "hybrid: learned first stage" in capsys.readouterr().out
    depth = np.load(out)
    assert depth.shape == (96, 64) and abs(np.nanmedian(depth) / FAR - 1) < 0.02
    assert np.isfinite(depth[:, 40:]).all()  # --dense: every pixel that sees through the prism
    assert _run(scene, scene / "far.png", "--out", tmp_path / "x.npy", "--model", "hybrid", "--hypotheses", 10) == 2
    assert "--hypotheses set the classical model's options, not --model hybrid's" in capsys.readouterr().err
    if backend == "torch":  # --weights alone: a hybrid weights file
        from prismstereo.learned import HybridArchitecture, HybridStereo

        torch.manual_seed(0)
        rig = thesis_setup1().downscaled(8)
        weights = HybridStereo(rig, (400.0, 900.0), weights=None, architecture=HybridArchitecture(channels=4)).save(
            tmp_path / "h.pt")
        assert _run(scene, scene / "far.png", "--out", tmp_path / "w.npy", "--weights", weights,
                    "--z-range", 400, 900) == 0
        assert "5 x 4 ch" in capsys.readouterr().out


def test_export_learned(scene, tmp_path, capsys):
    assert main(["export", "--rig", str(scene / "small.json"), "--out", str(tmp_path / "l.onnx"), "--model", "learned",
                 "--z-range", "400", "900"]) == 0
    from prismstereo.export import OnnxDepth

    runner = OnnxDepth(tmp_path / "l.onnx")
    assert '"model": "LearnedStereo"' in runner.metadata["prismstereo.config"]
    assert runner(torch.rand(1, 1, 96, 128)).depth.shape == (1, 1, 96, 64)


def test_an_interrupted_folder_run_leaves_whole_files_and_resumes(scene, tmp_path):
    """A real SIGINT to the command while it writes: one line, exit 130, only whole files; --skip-existing ends it."""
    import signal

    import cv2

    frames, out = tmp_path / "frames", tmp_path / "out"
    frames.mkdir()
    thesis_setup1().downscaled(4).to_json(tmp_path / "rig.json")  # 256 x 192: ~40 ms a frame
    frame = cv2.resize(cv2.imread(str(scene / "far.png")), (256, 192))
    total = 150  # ~6 s after the first file: this process wakes before the end even on a loaded host
    for k in range(total):
        cv2.imwrite(str(frames / f"f{k:03d}.png"), frame)
    args = ["depth", str(frames), "--rig", str(tmp_path / "rig.json"), "--out", str(out), "--z-range", "400", "700",
            "--no-temporal", "--model", "classical"]
    for _ in range(3):  # on a very loaded host this process may wake only after the whole run: then run it again
        shutil.rmtree(out, ignore_errors=True)
        proc = subprocess.Popen([sys.executable, "-u", "-m", "prismstereo.cli", *args], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 60
        while not list(out.glob("*.npy")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.005)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
        if proc.returncode != 0 or len(list(out.glob("*.npy"))) < total:
            break
    assert proc.returncode == 130 and "Traceback" not in err, err
    written = sorted(out.iterdir())
    assert err.strip().splitlines()[-1] == (f"prismstereo: interrupted: {len(written)} of {total} depth maps "
                                            "written; rerun with --skip-existing to resume")
    assert 0 < len(written) < total and all(p.suffix == ".npy" and not p.name.startswith(".") for p in written)
    for path in written:
        assert np.load(path).shape == (192, 128)  # whole files
    keep = max(40, len(written))  # the resumed run: the first `keep` frames (the time of 40 at most, not of 150)
    for path in sorted(frames.iterdir())[keep:]:
        path.unlink()
    assert main([*args, "--skip-existing"]) == 0
    assert len(list(out.iterdir())) == keep


def test_sigterm_ends_a_run_with_status_143(scene, tmp_path, monkeypatch, capsys):
    import signal

    from prismstereo.jobs import Pipeline

    write = Pipeline._write

    def write_then_terminate(self, *args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        return write(self, *args, **kwargs)

    monkeypatch.setattr(Pipeline, "_write", write_then_terminate)
    previous = signal.getsignal(signal.SIGTERM)
    assert _run(scene, scene / "far.png", scene / "near.png", "--out", tmp_path / "o", "--z-range", 400, 700) == 143
    assert capsys.readouterr().err.strip().startswith("prismstereo: interrupted: ")
    assert signal.getsignal(signal.SIGTERM) == previous
    assert not list((tmp_path / "o").glob(".*"))
