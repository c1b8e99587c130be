"""The walk of docs/usage.md, "Calibration from scratch": boards rendered through a rig, calibrated from its nominal
values, then depth through the calibrated rig file."""

import numpy as np

from prismstereo import thesis_setup1
from prismstereo.cli import main
from prismstereo.geometry.rig import BiPrismRig


def test_render_boards_calibrate_then_depth(tmp_path, capsys):
    nominal = thesis_setup1().downscaled(4)  # 256 x 192
    true = nominal.replace(prism_tilt_deg=(0.0, 0.0, 0.25), alpha_deg=6.5, apex_distance_mm=172.0)
    nominal.to_json(tmp_path / "nominal.json")
    true.to_json(tmp_path / "true.json")  # the camera: only its captures are used below
    boards, rig = tmp_path / "boards", str(tmp_path / "true.json")
    assert main(["render", "--rig", rig, "--scene", "board", "--target", "checkerboard:4x7:6", "--views", "4",
                 "--depth-mm", "550", "850", "--supersample", "1", "--noise", "0.008", "--out", str(boards)]) == 0
    views = sorted(str(p) for p in boards.glob("board_*.png"))
    assert len(views) == 4 and len(list(boards.glob("board_*.npz"))) == 4
    assert main(["calibrate", "--rig", str(tmp_path / "nominal.json"), *views, "--target", "checkerboard:4x7:6",
                 "--out", str(tmp_path / "calibrated.json"), "--quiet"]) == 0
    calibrated = BiPrismRig.from_json(tmp_path / "calibrated.json")
    assert abs(calibrated.prism_tilt_deg[2] - 0.25) < 0.05
    plane = tmp_path / "plane.png"
    assert main(["render", "--rig", rig, "--scene", "plane", "--depth-mm", "600", "--supersample", "1", "--out",
                 str(plane)]) == 0
    errors = {}
    for name in ("nominal", "calibrated"):
        out = tmp_path / f"{name}.npy"
        assert main(["depth", str(plane), "--rig", str(tmp_path / f"{name}.json"), "--out", str(out),
                     "--z-range", "450", "800"]) == 0
        errors[name] = float(np.nanmedian(np.abs(np.load(out) / 600.0 - 1)))
    # the prism's angle and distance move the depth 2.8 %; 4 small checkerboards at 256 x 192 leave ~1 % (a ChArUco
    # board or scenes do better: docs/usage.md)
    assert errors["nominal"] > 0.02 and errors["calibrated"] < errors["nominal"] / 2, errors
    text = capsys.readouterr().out
    assert text.count("depth uncertainty from the calibration") == 1


def test_render_a_charuco_board_the_detector_finds(tmp_path):
    from prismstereo.calibration import detect_board, parse_target
    from prismstereo.io import read_image

    rig = thesis_setup1().downscaled(4)
    rig.to_json(tmp_path / "rig.json")
    spec = "charuco:10x8:12:9:DICT_4X4_50"
    assert main(["render", "--rig", str(tmp_path / "rig.json"), "--scene", "board", "--target", spec, "--depth-mm",
                 "550", "--pose-deg", "20", "10", "0", "--supersample", "1", "--out", str(tmp_path / "c.png")]) == 0
    found = detect_board(read_image(tmp_path / "c.png"), rig, parse_target(spec))
    assert len(found.left.ids) >= 8 and len(found.right.ids) >= 8
