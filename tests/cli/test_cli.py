import json
import subprocess
import sys

import pytest
import torch

from prismstereo import BiPrismRig, __version__, thesis_setup1
from prismstereo.cli import main


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"prismstereo {__version__}"


def test_console_script_installed():
    out = subprocess.run([sys.executable, "-m", "prismstereo.cli", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and __version__ in out.stdout


def test_version_and_one_commands_parser_need_no_torch():
    """``prismstereo --version``, ``prismstereo depth --help`` and parsing depth's flags import only the command's
    module, which imports torch when it runs."""
    code = ("import sys, contextlib, io; from prismstereo.cli import build_parser, main\n"
            "args = build_parser(['depth']).parse_args(['depth', 'a.png', '--rig', 'r', '--out', 'o.npy', '--backend',"
            " 'onnx', '--model', 'classical'])\n"
            "for argv in (['--version'], ['depth', '--help']):\n"
            "    with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
            "        main(argv)\n"
            "print(args.backend, args.model, 'torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["onnx", "classical", "False"]


def test_the_install_left_bytecode_for_start_up():
    """``make``'s install compiles what ``prismstereo depth`` imports: a host that sets PYTHONDONTWRITEBYTECODE does
    not compile torch, onnxruntime or the package at every start."""
    import importlib.util
    import os

    import onnxruntime

    import prismstereo.jobs.pipeline

    for module in (torch, torch.nn.modules.conv, onnxruntime, prismstereo.jobs.pipeline):
        assert os.path.exists(importlib.util.cache_from_source(module.__file__)), module.__file__


def test_rig_show_file(tmp_path, capsys):
    path = tmp_path / "rig.json"
    thesis_setup1().replace(prism_offset_x_mm=2.0).to_json(path)
    assert main(["rig", "show", str(path)]) == 0
    out = capsys.readouterr().out
    assert "prism_offset_x_mm    2.0" in out
    for half in ("left", "right"):
        for method in ("two-point", "least-squares"):
            assert f"{half} virtual camera ({method})" in out
    assert "non-centrality (mm)" in out and "pinhole error (px)" in out


def test_rig_show_preset(capsys):
    assert main(["rig", "show", "thesis_setup1"]) == 0
    out = capsys.readouterr().out
    assert "beta (rad)              +0.05376" in out
    assert "beta (rad)              -0.05376" in out
    assert "centre C (mm)           [-9.1714" in out


def test_rig_preset_writes_json(tmp_path, capsys):
    path = tmp_path / "setup2.json"
    assert main(["rig", "preset", "thesis_setup2", "--out", str(path)]) == 0
    assert BiPrismRig.from_json(path).alpha_deg == 21.8
    assert main(["rig", "preset", "thesis_setup1"]) == 0
    assert json.loads(capsys.readouterr().out.split("\n", 1)[1])["alpha_deg"] == 6.4


@pytest.mark.parametrize(
    "content,message",
    [(None, "rig file not found"), ("{oops", "not valid JSON"), ('{"alpha_deg": 6.4}', "missing required field"),
     (thesis_setup1().replace(prism_offset_x_mm=40.0).to_json(), "no pixel of the right half-image sees through")],
)
def test_rig_show_bad_files(tmp_path, capsys, content, message):
    path = tmp_path / "rig.json"
    if content is not None:
        path.write_text(content)
    assert main(["rig", "show", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("prismstereo: error:") and message in err


def test_no_command_prints_help(capsys):
    assert main([]) == 2
    assert "usage: prismstereo" in capsys.readouterr().err


def test_demo(tmp_path, capsys):
    import numpy as np

    assert main(["demo", "--scale", "4", "--out", str(tmp_path / "demo")]) == 0
    out = capsys.readouterr().out
    assert "left virtual camera (least-squares)" in out
    lines = [ln for ln in out.splitlines() if ln.strip().startswith("depth ")]
    assert len(lines) == 4
    for line in lines:  # the exact round trip is far below a micro-pixel
        assert float(line.split("max error")[1].split("px")[0]) < 1e-6
    errors = [ln for ln in out.splitlines() if "relative depth error mean" in ln]  # the hybrid, then the classical
    assert len(errors) == 2 and "  hybrid: learned first stage" in out
    assert out.split("  classical: ")[1].splitlines()[0].endswith("(the default on this sensor)")  # 256 x 192
    for line in errors:
        assert float(line.split("mean ")[1].split("%")[0]) < 1.0
    depth = np.load(tmp_path / "demo" / "depth.npy")
    assert depth.shape == (192, 128) and np.nanmin(depth) > 350 and np.nanmax(depth) < 750
    assert (tmp_path / "demo" / "depth_preview.png").exists() and (tmp_path / "demo" / "capture.png").exists()


def _small_rig(tmp_path):
    rig = thesis_setup1().downscaled(8)
    path = tmp_path / "small.json"
    rig.to_json(path)
    return path


def test_render_writes_image_and_ground_truth(tmp_path, capsys):
    import numpy as np

    from prismstereo.io import read_image

    out = tmp_path / "capture.png"
    code = main(["render", "--rig", str(_small_rig(tmp_path)), "--scene", "plane", "--depth-mm", "525", "--out",
                 str(out), "--seed", "3", "--noise", "0.004", "--supersample", "2"])
    assert code == 0 and out.exists()
    img = read_image(out)
    assert img.shape == (1, 96, 128)
    gt = np.load(out.with_suffix(".npz"))
    assert gt["depth"].shape == (96, 128) and np.nanmax(gt["depth"]) == np.float32(525.0)
    assert gt["covisible"].dtype == bool and gt["covisible"].any() and gt["match_uv"].shape == (96, 128, 2)
    assert "plane_525mm" in str(gt["scene"])
    assert "co-visible" in capsys.readouterr().out


def test_render_batch_and_16_bit_rgb(tmp_path):
    from prismstereo.io import read_image

    out = tmp_path / "batch"
    code = main(["render", "--rig", str(_small_rig(tmp_path)), "--scene", "step", "--depth-mm", "400", "500",
                 "--out", str(out), "--bits", "16", "--rgb", "--supersample", "1"])
    assert code == 0
    files = sorted(p.name for p in out.iterdir())
    assert files == ["step_400_600mm.npz", "step_400_600mm.png", "step_500_700mm.npz", "step_500_700mm.png"]
    img = read_image(out / "step_400_600mm.png")
    assert img.shape == (3, 96, 128)
    assert ((img * 65535).round() % 257 != 0).any()  # really 16-bit levels


@pytest.mark.parametrize(
    "extra,message",
    [(["--scene", "plane", "--depth-mm", "100"], "not beyond the prism's back plane"),
     (["--scene", "middlebury", "--depth-mm", "450"], "needs --middlebury DIR"),
     (["--scene", "plane", "--depth-mm", "400", "500"], "--out must be a directory"),
     (["--scene", "board", "--depth-mm", "500"], "--scene board needs --target SPEC"),
     (["--scene", "board", "--depth-mm", "500", "--target", "checkerboard:4x7"], "cannot parse target"),
     (["--scene", "board", "--depth-mm", "500", "--target", "charuco:12x9:10:7:DICT_4X4_50"],
      "a 12x9 ChArUco board has 54 markers but DICT_4X4_50 only 50"),
     (["--scene", "plane", "--depth-mm", "500", "--views", "3"], "--views renders boards at random poses"),
     (["--scene", "board", "--depth-mm", "500", "--views", "0"], "--views must be >= 1"),
     (["--scene", "board", "--depth-mm", "500", "--views", "2", "--target", "checkerboard:4x7:6"],
      "--views render a batch: --out must be a directory")],
)
def test_render_errors(tmp_path, capsys, extra, message):
    code = main(["render", "--rig", str(_small_rig(tmp_path)), "--out", str(tmp_path / "x.png"), *extra])
    assert code == 2
    assert message in capsys.readouterr().err


def test_match_writes_disparity(tmp_path, capsys):
    import numpy as np

    from prismstereo.io import write_image
    from tests.matching.test_cost_select import shifted_pair

    left, right = shifted_pair(5.0, h=40, w=100, seed=1)
    write_image(tmp_path / "l.png", left[0], bits=16)
    write_image(tmp_path / "r.png", right[0], bits=16)
    out = tmp_path / "disp.npy"
    assert main(["match", str(tmp_path / "l.png"), str(tmp_path / "r.png"), "--disparities", "12", "--out",
                 str(out)]) == 0
    disp = np.load(out)
    assert disp.shape == (40, 100) and disp.dtype == np.float32
    assert abs(np.nanmedian(disp[5:-5, 20:-5]) - 5.0) < 0.1
    assert "passed the checks" in capsys.readouterr().out
    # --no-fill: NaN wherever the checks failed (the 5 columns the right view cannot see among them)
    checked = tmp_path / "checked.npy"
    assert main(["match", str(tmp_path / "l.png"), str(tmp_path / "r.png"), "--disparities", "12", "--out",
                 str(checked), "--no-fill"]) == 0
    only = np.load(checked)
    assert np.isnan(only[:, :5]).mean() > 0.9 and np.isnan(only).sum() > np.isnan(disp).sum()
    assert abs(np.nanmedian(only[5:-5, 20:-5]) - 5.0) < 0.1


def test_match_errors(tmp_path, capsys):
    from prismstereo.io import write_image

    write_image(tmp_path / "a.png", torch.rand(1, 20, 30))
    write_image(tmp_path / "b.png", torch.rand(1, 20, 31))
    assert main(["match", str(tmp_path / "a.png"), str(tmp_path / "b.png"), "--disparities", "8", "--out",
                 str(tmp_path / "d.npy")]) == 2
    assert "differ in size" in capsys.readouterr().err
    assert main(["match", str(tmp_path / "a.png"), str(tmp_path / "missing.png"), "--disparities", "8", "--out",
                 str(tmp_path / "d.npy")]) == 2
    assert "image not found" in capsys.readouterr().err
    assert main(["match", str(tmp_path / "a.png"), str(tmp_path / "a.png"), "--disparities", "8", "--out",
                 str(tmp_path / "d.png")]) == 2
    assert "must end in .npy" in capsys.readouterr().err
