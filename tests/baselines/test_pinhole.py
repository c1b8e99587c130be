import cv2
import numpy as np
import pytest
import torch

from prismstereo import CalibrationError, ShapeError
from prismstereo.baselines import Pinhole, pinhole_from_opencv, pinhole_from_virtual, project_pinhole
from prismstereo.geometry import virtual_camera
from tests.baselines.conftest import RIG

pytestmark = pytest.mark.usefixtures("one_thread")

F64 = torch.float64


def test_pinhole_from_opencv_pose_convention():
    rvec = np.array([0.1, -0.2, 0.05])
    t = np.array([3.0, -1.0, 20.0])
    k = np.array([[500.0, 0, 100], [0, 510.0, 80], [0, 0, 1]])
    cam = pinhole_from_opencv(k, np.array([0.1, -0.01, 0.001, 0.002]), rvec, t)
    assert isinstance(cam, Pinhole) and cam.distortion.shape == (5,) and float(cam.distortion[4]) == 0.0
    r_cv = cv2.Rodrigues(rvec)[0]
    # the same camera from the rotation matrix; X_cam = R^T (X - C) equals OpenCV's R_cv X + t
    same = pinhole_from_opencv(torch.from_numpy(k), None, torch.from_numpy(r_cv), torch.from_numpy(t))
    torch.testing.assert_close(same.rotation, cam.rotation)
    x = torch.tensor([1.0, 2.0, 300.0], dtype=F64)
    torch.testing.assert_close(cam.rotation.T @ (x - cam.centre), torch.from_numpy(r_cv @ x.numpy() + t))


@pytest.mark.parametrize(("args", "match"), [
    ((np.eye(2), None, np.zeros(3), np.zeros(3)), "matrix must hold 9"),
    ((np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3)), "4 or 5 finite coefficients"),
    ((np.eye(3), None, np.zeros(3), np.array([0.0, np.nan, 1.0])), "translation must hold 3 finite"),
    ((np.eye(3), None, np.zeros((2, 2)), np.zeros(3)), "rotation must hold 9"),
])
def test_pinhole_from_opencv_errors(args, match):
    with pytest.raises(CalibrationError, match=match):
        pinhole_from_opencv(*args)


@pytest.mark.parametrize("method", ["two_point", "least_squares"])
def test_pinhole_from_virtual_projects_like_kornia(method):
    vc = virtual_camera(RIG, "left", method)
    cam = pinhole_from_virtual(vc)
    assert cam.matrix.shape == (3, 3) and bool((cam.distortion == 0).all())
    torch.testing.assert_close(cam.centre, vc.centre)
    pts = torch.tensor([[-20.0, 10.0, 400.0], [5.0, -7.0, 900.0]], dtype=F64)
    torch.testing.assert_close(project_pinhole(cam, pts), vc.camera.project(pts), atol=1e-6, rtol=0)


def test_pinhole_from_virtual_error():
    with pytest.raises(CalibrationError, match="camera must be a VirtualCamera"):
        pinhole_from_virtual(np.eye(3))


def test_project_pinhole_shape_and_errors():
    cam = pinhole_from_opencv(np.eye(3), None, np.zeros(3), np.zeros(3))
    assert project_pinhole(cam, torch.ones(4, 3, dtype=F64)).shape == (4, 2)
    with pytest.raises(ShapeError, match=r"points must have shape \(N, 3\)"):
        project_pinhole(cam, torch.ones(4, 2))
