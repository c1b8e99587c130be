import numpy as np
import pytest
import torch

from prismstereo import CalibrationError
from prismstereo.baselines import TsaiResult, calibrate_tsai, pinhole_from_opencv, project_pinhole, tsai_camera
from prismstereo.geometry import virtual_cameras
from tests.baselines.conftest import RIG, SIZE

pytestmark = pytest.mark.usefixtures("one_thread")

F64 = torch.float64


def board_groups() -> list[torch.Tensor]:
    """Three 5 x 4-point boards at different poses in front of a camera at the origin (a non-planar target)."""
    g = torch.stack(torch.meshgrid(torch.arange(5.0), torch.arange(4.0), indexing="xy"), -1).reshape(-1, 2)
    flat = torch.cat([g * 20 - 40, torch.zeros(20, 1)], 1).to(F64)
    rot = torch.tensor([[0.9, 0.0, 0.43589], [0.0, 1.0, 0.0], [-0.43589, 0.0, 0.9]], dtype=F64)
    return [flat + torch.tensor([0.0, 0, 500.0]), flat @ rot.T + torch.tensor([30.0, 10, 600]),
            flat @ rot + torch.tensor([-30.0, -10, 450])]


@pytest.mark.parametrize("distortion", [None, np.array([0.05, -0.2, 0.001, -0.002, 0.0])])
def test_tsai_camera_recovers_a_pinhole(distortion):
    k = np.array([[800.0, 0, 330], [0, 790.0, 235], [0, 0, 1]])
    true = pinhole_from_opencv(k, distortion, np.array([0.02, -0.05, 0.01]), np.array([-9.0, 1.0, 2.0]))
    groups = board_groups()
    out = tsai_camera(groups, [project_pinhole(true, p) for p in groups], (640, 480))
    assert out.rms_px < 1e-3 and out.initial_matrix.shape == (3, 3)
    torch.testing.assert_close(out.camera.matrix, true.matrix, atol=1e-2, rtol=0)
    torch.testing.assert_close(out.camera.centre, true.centre, atol=1e-3, rtol=0)
    torch.testing.assert_close(out.camera.rotation, true.rotation, atol=1e-5, rtol=0)  # OpenCV works in float32


def test_calibrate_tsai_centres_near_least_squares(board_views):
    out = calibrate_tsai(board_views.detections, board_views.references, SIZE)
    assert isinstance(out, TsaiResult) and out.views == tuple(range(8)) and float(out.rms_px.max()) < 0.3
    for cam, ref in zip(out.cameras, virtual_cameras(RIG), strict=True):
        assert float((cam.centre[:2] - ref.centre[:2]).abs().max()) < 0.3
        assert abs(float(cam.centre[2] - ref.centre[2])) < 5.0


def test_tsai_camera_errors():
    groups = board_groups()
    uv = [torch.zeros(20, 2, dtype=F64) for _ in groups]
    with pytest.raises(CalibrationError, match=">= 2 groups"):
        tsai_camera(groups[:1], uv[:1], SIZE)
    with pytest.raises(CalibrationError, match="group 1: points must be"):
        tsai_camera(groups, [uv[0], uv[1][:5], uv[2]], SIZE)
    with pytest.raises(CalibrationError, match="group 0: non-finite"):
        tsai_camera([groups[0] * float("nan")] + groups[1:], uv, SIZE)
    with pytest.raises(CalibrationError, match="not coplanar"):
        tsai_camera([torch.cat([groups[0][:10], groups[1][10:]])] + groups[1:], uv, SIZE)
    with pytest.raises(CalibrationError, match="nearly\\) coplanar"):
        tsai_camera([groups[0], groups[0] + torch.tensor([5.0, 0, 0], dtype=F64)], uv[:2], SIZE)
    with pytest.raises(CalibrationError, match="image_size"):
        tsai_camera(groups, uv, (0, 0))


def test_calibrate_tsai_errors(board_views):
    with pytest.raises(CalibrationError, match="one entry per detection"):
        calibrate_tsai(board_views.detections, board_views.references[:2], SIZE)
    with pytest.raises(CalibrationError, match="left half: need >= 2 groups"):
        calibrate_tsai(board_views.detections, [board_views.references[0]] + [None] * 7, SIZE)
