import pytest
import torch

from prismstereo import CalibrationError, OptionError
from prismstereo.baselines import ZhangResult, calibrate_zhang, check_image_size
from prismstereo.calibration import ViewDetection
from prismstereo.geometry import virtual_cameras
from tests.baselines.conftest import BOARD, RIG, SIZE

pytestmark = pytest.mark.usefixtures("one_thread")

F64 = torch.float64


@pytest.fixture(scope="module")
def least_squares():
    return virtual_cameras(RIG)


def test_zhang_registered_centres_near_least_squares(board_views, least_squares):
    """Zhang on boards rendered through the rig, registered by the boards' known corners: its virtual cameras
    sit where our all-pixel least-squares ones do (across the axis to 0.3 mm; along it, where a narrow field of
    view trades the centre's distance against the focal length, to 10 mm: changes of the corners' positions by
    less than 0.1 px RMS move it by several mm)."""
    out = calibrate_zhang(board_views.detections, BOARD, SIZE, reference_points=board_views.references)
    assert isinstance(out, ZhangResult) and out.frame == "real" and out.views == tuple(range(8))
    assert float(out.rms_px.max()) < 0.3 and out.registration_rms_mm < 2.0
    for cam, ref in zip(out.cameras, least_squares, strict=True):
        assert cam.matrix.shape == (3, 3) and cam.distortion.shape == (5,)
        torch.testing.assert_close(cam.rotation.T @ cam.rotation, torch.eye(3, dtype=F64))
        assert float((cam.centre[:2] - ref.centre[:2]).abs().max()) < 0.3
        assert abs(float(cam.centre[2] - ref.centre[2])) < 10.0
    baseline = (out.cameras.right.centre - out.cameras.left.centre).norm()
    ref_baseline = (least_squares.right.centre - least_squares.left.centre).norm()
    assert abs(float(baseline / ref_baseline) - 1) < 0.01
    # OpenCV's relative pose is the one between the two returned cameras
    left, right = out.cameras
    torch.testing.assert_close(out.rotation, right.rotation.T @ left.rotation)
    torch.testing.assert_close(out.translation, right.rotation.T @ (left.centre - right.centre))


def test_zhang_left_frame_and_fixed_intrinsics(board_views):
    out = calibrate_zhang(board_views.detections, BOARD, SIZE, stereo="fix_intrinsic")
    assert out.frame == "left" and out.registration_rms_mm != out.registration_rms_mm  # NaN
    torch.testing.assert_close(out.cameras.left.rotation, torch.eye(3, dtype=F64))
    torch.testing.assert_close(out.cameras.left.centre, torch.zeros(3, dtype=F64))
    assert 17.0 < -float(out.translation[0]) < 20.0  # the baseline, ~18.6 mm (T_z: weakly determined, see zhang.py)


def test_zhang_errors(board_views):
    dets, refs = board_views.detections, board_views.references
    with pytest.raises(CalibrationError, match="at least 3 views, got 2 of 8"):
        calibrate_zhang(dets[:2] + [ViewDetection(dets[2].left, None)] * 6, BOARD, SIZE)
    with pytest.raises(OptionError, match="Unknown stereo 'joint'"):
        calibrate_zhang(dets, BOARD, SIZE, stereo="joint")
    with pytest.raises(CalibrationError, match="image_size must be"):
        calibrate_zhang(dets, BOARD, (256,))
    with pytest.raises(CalibrationError, match="one entry per detection"):
        calibrate_zhang(dets, BOARD, SIZE, reference_points=refs[:3])
    with pytest.raises(CalibrationError, match=r"must be a \(28, 3\) tensor"):
        calibrate_zhang(dets, BOARD, SIZE, reference_points=[r[:5] for r in refs])
    with pytest.raises(CalibrationError, match="at least 3 non-collinear"):
        calibrate_zhang(dets, BOARD, SIZE, reference_points=[None] * len(dets))


@pytest.mark.parametrize("size", [(0, 10), (10.5, 3), "ab", (1, 2, 3)])
def test_check_image_size_errors(size):
    assert check_image_size((256, 192)) == (256, 192)
    with pytest.raises(CalibrationError, match="image_size must be"):
        check_image_size(size)
