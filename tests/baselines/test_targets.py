import pytest
import torch

from prismstereo import CalibrationError
from prismstereo.baselines import checkerboard_corners, reference_points
from prismstereo.calibration import ViewDetection
from prismstereo.geometry import project_points
from prismstereo.synthetic import checkerboard_target, fronto_parallel_plane
from tests.baselines.conftest import BOARD, RIG

pytestmark = pytest.mark.usefixtures("one_thread")

F64 = torch.float64


def test_checkerboard_corners_reference_values():
    corners = checkerboard_corners(checkerboard_target((0.0, 0.0, 600.0), rows=8, cols=5, square_mm=6.0))
    assert corners.shape == (28, 3)
    torch.testing.assert_close(corners[:4], torch.tensor([[-9.0, -18.0, 600.0], [-3.0, -18.0, 600.0],
                                                          [3.0, -18.0, 600.0], [9.0, -18.0, 600.0]], dtype=F64))
    torch.testing.assert_close(corners[-1], torch.tensor([9.0, 18.0, 600.0], dtype=F64))
    tilted = checkerboard_corners(checkerboard_target((0.0, 0.0, 600.0), (30.0, 0.0, 0.0), rows=8, cols=5))
    torch.testing.assert_close(tilted.mean(0), torch.tensor([0.0, 0.0, 600.0], dtype=F64))


def test_checkerboard_corners_rejects_other_scenes():
    with pytest.raises(CalibrationError, match="is not a checkerboard target"):
        checkerboard_corners(fronto_parallel_plane(RIG, 500.0))


def test_reference_points_match_detections(board_views):
    for det, ref in zip(board_views.detections, board_views.references, strict=True):
        assert ref.shape == (BOARD.num_points, 3)
        for half in ("left", "right"):
            found = getattr(det, half)
            proj = project_points(RIG, ref[found.ids], half)
            assert float((proj.uv - found.uv).norm(dim=1).max()) < 1.0  # corner detection noise at 256 x 192


def test_reference_points_errors(board_views):
    scene, det = board_views.scenes[0], board_views.detections[0]
    with pytest.raises(CalibrationError, match="neither half"):
        reference_points(RIG, checkerboard_corners(scene), ViewDetection(None, None), BOARD)
    shifted = checkerboard_corners(scene) + torch.tensor([30.0, 0.0, 0.0], dtype=F64)
    with pytest.raises(CalibrationError, match="wrong scene or rig"):
        reference_points(RIG, shifted, det, BOARD)
