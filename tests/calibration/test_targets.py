import cv2
import numpy as np
import pytest
import torch

from prismstereo import CalibrationError
from prismstereo.calibration import Board, detect_board, parse_target
from prismstereo.calibration.targets import to_gray_u8
from prismstereo.geometry.projection import project_points
from tests.calibration.conftest import BOARD, NOMINAL, board_captures, board_scenes


def test_parse_target_round_trip_and_errors():
    board = parse_target("checkerboard:9x6:25")
    assert (board.kind, board.cols, board.rows, board.square_mm, board.num_points) == ("checkerboard", 9, 6, 25.0, 54)
    assert parse_target(board.describe()) == board
    charuco = parse_target("charuco:5x7:30:22:DICT_4X4_50")
    assert charuco.num_points == 24 and parse_target(charuco.describe()) == charuco
    for bad in ("checkerboard:9x6", "circles:9x6:25", "checkerboard:9by6:25", "charuco:5x7:30:22"):
        with pytest.raises(CalibrationError, match="cannot parse target"):
            parse_target(bad)
    with pytest.raises(CalibrationError, match="unknown ArUco dictionary 'DICT_NOPE'.*DICT_4X4_50"):
        parse_target("charuco:5x7:30:22:DICT_NOPE")
    with pytest.raises(CalibrationError, match="marker_mm must be in"):
        parse_target("charuco:5x7:30:30:DICT_4X4_50")
    with pytest.raises(CalibrationError, match="COLSxROWS >= 3"):
        Board(kind="checkerboard", cols=2, rows=6, square_mm=10.0)
    with pytest.raises(CalibrationError, match="COLS != ROWS"):
        parse_target("checkerboard:6x6:10")


def test_board_points_follow_opencv_order():
    pts = parse_target("checkerboard:4x3:10").points()
    assert pts.shape == (12, 3) and pts.dtype == torch.float64
    assert pts[1].tolist() == [10.0, 0.0, 0.0] and pts[4].tolist() == [0.0, 10.0, 0.0]
    charuco = parse_target("charuco:5x4:10:7:DICT_4X4_50")
    cv = charuco.charuco_board().getChessboardCorners()
    assert np.allclose(charuco.points().numpy(), cv - cv[0])


def test_checkerboard_corners_in_both_halves_are_the_exact_projections():
    """Detected corners of a rendered board are the exact projections of the board points through each half, in
    the same order in both halves (OpenCV may start at either end: the board frame is then turned by a half
    turn, for both halves alike)."""
    scenes = board_scenes(3, seed=11)
    cap = board_captures(NOMINAL, 3, seed=11)
    for k in range(3):
        det = detect_board(cap.image[k], NOMINAL, BOARD)
        assert det.left is not None and det.right is not None
        plane = scenes[k].surfaces[0]
        # checkerboard_target's frame: inner corner (i, j) at corner + (j + 1) sq u + (i + 1) sq v
        origin = plane.point + 6.0 * plane.u_axis + 6.0 * plane.v_axis
        errors = {}
        for turned in (False, True):
            for half, d in (("left", det.left), ("right", det.right)):
                p = BOARD.points()[d.ids]
                s, t = (18.0 - p[:, :1], 36.0 - p[:, 1:2]) if turned else (p[:, :1], p[:, 1:2])
                exact = project_points(NOMINAL, origin + s * plane.u_axis + t * plane.v_axis, half).uv
                errors[turned, half] = float((exact - d.uv).norm(dim=-1).max())
        best = min((False, True), key=lambda tr: errors[tr, "left"])
        assert errors[best, "left"] < 0.5 and errors[best, "right"] < 0.5, errors


def test_charuco_ids_in_both_halves():
    board = parse_target("charuco:5x4:10:7:DICT_4X4_50")
    img = board.charuco_board().generateImage((100, 80), marginSize=6)
    canvas = np.full((NOMINAL.image_height, NOMINAL.image_width), 255, np.uint8)
    split = NOMINAL.reference_width
    canvas[50:130, 10:110] = img
    canvas[60:140, split + 10:split + 110] = img
    det = detect_board(canvas, NOMINAL, board)
    assert det.left is not None and det.right is not None
    assert sorted(det.left.ids.tolist()) == sorted(det.right.ids.tolist()) == list(range(board.num_points))
    order_l, order_r = det.left.ids.argsort(), det.right.ids.argsort()
    shift = det.right.uv[order_r] - det.left.uv[order_l]
    assert torch.allclose(shift, torch.tensor([float(split), 10.0], dtype=torch.float64), atol=0.05)


def test_detection_errors_and_misses():
    with pytest.raises(CalibrationError, match="image is 100x50 px but the rig's sensor is 256x192"):
        detect_board(torch.zeros(1, 50, 100), NOMINAL, BOARD)
    blank = detect_board(np.full((192, 256), 128, np.uint8), NOMINAL, BOARD)
    assert blank.left is None and blank.right is None
    bgr = cv2.cvtColor(np.full((4, 5), 200, np.uint8), cv2.COLOR_GRAY2BGR)
    assert to_gray_u8(bgr).shape == (4, 5) and to_gray_u8(bgr)[0, 0] == 200
    assert to_gray_u8(torch.full((3, 4, 5), 0.5))[0, 0] == 128
    with pytest.raises(CalibrationError, match="image must be"):
        to_gray_u8(torch.zeros(2, 3, 4, 5))
    assert to_gray_u8(torch.full((1, 4, 5), 200, dtype=torch.uint8))[0, 0] == 200
    with pytest.raises(CalibrationError, match=r"\(H, W\) or \(H, W, 3\)"):
        to_gray_u8(np.zeros((3, 4, 5), np.uint8))
