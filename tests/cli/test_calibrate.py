import contextlib
import io
import json
import re

import cv2
import pytest

from prismstereo.cli import main
from prismstereo.geometry.rig import BiPrismRig
from tests.calibration.conftest import NOMINAL, board_captures


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    """Six board captures and one textured scene (scene0.png) through a rolled rig with a mild lens."""
    from prismstereo.synthetic import ImageFormation, render, slanted_plane

    folder = tmp_path_factory.mktemp("bench")
    true = NOMINAL.replace(prism_tilt_deg=(0.0, 0.0, 0.25), distortion=(-0.07, 0.0, 0.0, 0.0, 0.0))
    cap = board_captures(true, 6, seed=7)
    scene = render(true, slanted_plane(true, 600.0, 20.0, seed=1), ImageFormation(noise_sigma=2 / 255, seed=3))
    paths = []
    for name, image in [*((f"board{k}", im) for k, im in enumerate(cap.image)), ("scene0", scene.image[0])]:
        path = folder / f"{name}.png"
        cv2.imwrite(str(path), (image[0].numpy() * 255).round().astype("uint8"))
        paths.append(str(path))
    rig = folder / "nominal.json"
    NOMINAL.to_json(rig)
    return folder, str(rig), paths[:-1]


@pytest.fixture(scope="module")
def default_run(bench):
    """One CLI calibration of the bench's boards and its scene together (--scenes) with the default (symmetric)
    corners, p1 and p2 fixed and a residual plot: its exit code, printed report, output paths and the nominal rig
    file's text before the run. Checked by test_calibrate_cli_writes_a_rig_and_reports and the baseline of
    test_calibrate_cli_corner_methods (one fit instead of two; the boards' corner RMS either way)."""
    folder, rig, paths = bench
    out, plot = folder / "calibrated.json", folder / "residuals.png"
    before = (folder / "nominal.json").read_text()
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = main(["calibrate", "--rig", rig, *paths, "--out", str(out), "--target", "checkerboard:4x7:6",
                     "--scenes", str(folder / "scene0.png"), "--fix", "p1", "p2", "--plot", str(plot), "--quiet"])
    return code, printed.getvalue(), out, plot, before


def test_calibrate_cli_writes_a_rig_and_reports(bench, default_run):
    folder, rig, paths = bench
    code, text, out, plot, before = default_run
    assert code == 0
    assert text.startswith("Calibrated from 6 views") and "board5.png" in text and f"wrote {out}" in text
    assert "what each input determines" in text and "scene0.png" in text
    calibrated = BiPrismRig.from_json(out)
    # k1's standard error from 6 whole checkerboards at 256 x 192 is 0.05-0.1 (the report's); roll's ~0.01 deg
    assert abs(calibrated.prism_tilt_deg[2] - 0.25) < 0.05 and abs(calibrated.distortion[0] + 0.07) < 0.1
    assert calibrated.distortion[2:4] == (0.0, 0.0)  # fixed
    assert json.loads(out.read_text())["image_width"] == 256
    assert plot.stat().st_size > 10_000
    assert (folder / "nominal.json").read_text() == before


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--target", "checkerboard:4x7"], "cannot parse target"),
        (["--target", "checkerboard:4x7:6", "--fix", "zoom"], "unknown rig parameter"),
        (["--target", "checkerboard:9x6:6"], "found in both halves of 0 of 6 views, need 3; found instead in 6 "
                                             "views: a checkerboard of 4x7 inner corners (is the target's size "
                                             "right?)"),
        (["--target", "charuco:5x8:6:4:DICT_4X4_250"], "found instead in 6 views: a checkerboard of 4x7"),
        (["--scenes", "scene.png"], "--scenes go beside the board captures of --target"),
    ],
)
def test_calibrate_cli_errors(bench, capsys, extra, message):
    folder, rig, paths = bench
    assert main(["calibrate", "--rig", rig, *paths, "--out", str(folder / "x.json"), "--quiet", *extra]) == 2
    assert message in capsys.readouterr().err


def test_calibrate_cli_refuses_bad_inputs(bench, capsys, tmp_path):
    folder, rig, paths = bench
    assert main(["calibrate", "--rig", rig, *paths, "--out", rig, "--target", "checkerboard:4x7:6"]) == 2
    assert "never overwritten" in capsys.readouterr().err
    assert main(["calibrate", "--rig", rig, *paths[:2], "--out", str(tmp_path / "x.json"),
                 "--target", "checkerboard:4x7:6"]) == 2
    assert "too few views: 2 captures" in capsys.readouterr().err
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), cv2.imread(paths[0])[:100])
    assert main(["calibrate", "--rig", rig, str(small), *paths, "--out", str(tmp_path / "x.json"),
                 "--target", "checkerboard:4x7:6"]) == 2
    assert "is 256x100 px but the rig's sensor is 256x192" in capsys.readouterr().err


def test_calibrate_cli_without_target_self_calibrates(tmp_path, capsys):
    from prismstereo.synthetic import ImageFormation, render, slanted_plane, step_scene

    true = NOMINAL.replace(prism_tilt_deg=(0.0, 0.0, 0.3))
    cap = render(true, [slanted_plane(true, 600.0, 20.0, seed=1), step_scene(true, 500.0, 800.0, seed=2)],
                 ImageFormation(supersample=2, noise_sigma=2 / 255, seed=3))
    paths = []
    for k, image in enumerate(cap.image):
        paths.append(str(tmp_path / f"scene{k}.png"))
        cv2.imwrite(paths[-1], (image[0].numpy() * 255).round().astype("uint8"))
    out = tmp_path / "self.json"
    assert main(["calibrate", "--rig", "thesis_setup1", *paths, "--out", str(out), "--quiet"]) == 2  # wrong size
    assert "is 256x192 px but the rig's sensor is 1024x768" in capsys.readouterr().err
    rig = tmp_path / "nominal.json"
    NOMINAL.to_json(rig)
    assert main(["calibrate", "--rig", str(rig), *paths, "--out", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "not observable from these captures" in text and "scene1.png" in text
    assert abs(BiPrismRig.from_json(out).prism_tilt_deg[2] - 0.3) < 0.03


def test_calibrate_cli_corner_methods(bench, default_run, capsys):
    """--corners opencv keeps the detectors' positions: a larger RMS than the default symmetric refinement (both
    fits with p1 and p2 fixed)."""
    folder, rig, paths = bench
    out = folder / "calibrated_opencv.json"
    assert main(["calibrate", "--rig", rig, *paths, "--out", str(out), "--target", "checkerboard:4x7:6",
                 "--fix", "p1", "p2", "--corners", "opencv", "--quiet"]) == 0
    rms = {method: float(re.search(r"RMS ([0-9.]+) px", text).group(1))
           for method, text in (("symmetric", default_run[1]), ("opencv", capsys.readouterr().out))}
    # measured 0.056 vs 0.140 px (ratio 0.40) with p1, p2 fixed; 0.056 vs 0.140 without (the fits before); bound 0.7
    assert rms["symmetric"] < 0.7 * rms["opencv"], rms
    with pytest.raises(SystemExit):
        main(["calibrate", "--rig", rig, *paths, "--out", str(folder / "x.json"), "--corners", "subpix"])
    assert "invalid choice: 'subpix'" in capsys.readouterr().err
