import pytest
import torch

from prismstereo import CalibrationError
from prismstereo.calibration import NAMES, Correspondences, calibrate_self, find_correspondences
from prismstereo.calibration.parameters import rig_vector, to_display
from prismstereo.calibration.report import format_report
from prismstereo.calibration.selfcal import SelfProblem
from prismstereo.calibration.solver import levenberg_marquardt
from prismstereo.synthetic import ImageFormation, render, slanted_plane, step_scene
from tests.calibration.conftest import NOMINAL

F64 = torch.float64


@pytest.fixture(scope="module")
def rolled():
    """Two textured captures through setup 1 (quarter resolution) with a rolled, shifted prism and a mild lens."""
    true = NOMINAL.replace(prism_tilt_deg=(0.0, 0.0, 0.3), prism_offset_x_mm=0.3)
    scenes = [slanted_plane(true, 600.0, 20.0, seed=1), step_scene(true, 500.0, 800.0, seed=2)]
    cap = render(true, scenes, ImageFormation(supersample=2, noise_sigma=2 / 255, seed=3))
    return true, cap


def test_correspondences_are_true_matches(rolled):
    true, cap = rolled
    corr = find_correspondences(cap.image[0], NOMINAL, view=0)
    assert corr.left.shape[0] > 100 and (corr.view == 0).all()
    # each right pixel is the renderer's exact match of its left pixel, to SIFT's accuracy
    u, v = corr.left[:, 0].round().long(), corr.left[:, 1].round().long()
    truth = cap.match_uv[0, :, v, u].T + (corr.left - corr.left.round())  # matches move with the left pixel
    ok = torch.isfinite(truth).all(dim=1)
    err = (truth[ok] - corr.right[ok]).norm(dim=-1)
    assert ok.float().mean() > 0.95 and err.median() < 0.3 and (err < 1.0).float().mean() > 0.95


def test_epipolar_residual_of_true_matches_is_zero_for_the_true_rig(rolled):
    """Solving only the depths, the true rig puts every true match on its exact epipolar curve."""
    true, cap = rolled
    w = true.reference_width
    ok = cap.covisible[0, 0, ::7, :w:7]
    v, u = torch.nonzero(ok, as_tuple=True)
    left = torch.stack([u * 7.0, v * 7.0], -1).to(F64)
    right = cap.match_uv[0, :, v * 7, u * 7].T
    corr = Correspondences(left, right, torch.zeros(len(u), dtype=torch.long))
    for rig, small in ((true, True), (NOMINAL, False)):
        problem = SelfProblem(rig, corr, [], sigma_px=1.0)
        fit = levenberg_marquardt(problem.residuals, problem.jacobian, problem.x0)
        rms = float((fit.cost / len(u)) ** 0.5)
        assert (rms < 1e-6) if small else (rms > 0.2), rms


def test_self_calibration_recovers_the_roll_and_reports_the_scale(rolled):
    true, cap = rolled
    result = calibrate_self(NOMINAL, list(cap.image))
    i = NAMES.index("roll_deg")
    truth = to_display(rig_vector(true))
    assert abs(float(result.after[i]) - 0.3) < 0.03 and float(result.data_share[i]) > 0.99
    # no target, no metric scale: what sets it cannot be determined and is held at nominal, reported
    assert {"alpha_deg", "refractive_index", "apex_distance_mm", "focal_length_mm"} <= set(result.unobservable)
    assert result.rig.alpha_deg == NOMINAL.alpha_deg
    z = ((result.after - truth) / result.std_error)[torch.isfinite(result.std_error)]
    assert result.rms_px < 0.3 and z.abs().max() < 5
    text = format_report(result)
    assert "not observable from these captures" in text and "(unobservable)" in text
    assert result.view_rms_px[:, 0].isnan().all() and result.poses.shape == (result.observations.uv.shape[0], 1)


def test_self_calibration_errors():
    with pytest.raises(CalibrationError, match="no captures"):
        calibrate_self(NOMINAL, [])
    with pytest.raises(CalibrationError, match="captures must be a list of images"):
        calibrate_self(NOMINAL, torch.zeros(1, 192, 256))
    # given correspondences pass the same gate as found ones: right pixels in the left half are not matches
    wrong = Correspondences(torch.tensor([[60.0, 90.0]] * 60, dtype=F64), torch.tensor([[20.0, 90.0]] * 60, dtype=F64),
                            torch.zeros(60, dtype=torch.long))
    with pytest.raises(CalibrationError, match="0 correspondences between the halves"):
        calibrate_self(NOMINAL, [wrong])
    with pytest.raises(CalibrationError, match="0 correspondences between the halves, need 50"):
        calibrate_self(NOMINAL, [torch.zeros(1, 192, 256)])
    with pytest.raises(CalibrationError, match="image is 10x10 px"):
        find_correspondences(torch.zeros(1, 10, 10), NOMINAL)
