import math

import kornia
import pytest
import torch

from prismstereo import CalibrationError
from prismstereo.calibration import DEFAULT_FIXED, NAMES, calibrate_board, detect_board
from prismstereo.calibration.board import BoardProblem, gather_observations, initial_poses, rigid_fit
from prismstereo.calibration.parameters import rig_vector, to_display, tolerance_vector, vector_to_rig
from prismstereo.calibration.report import format_report, plot_residuals
from prismstereo.calibration.solver import covariance, levenberg_marquardt, normal_inverse, unobservable
from prismstereo.synthetic import calibration_views
from tests.calibration.conftest import BOARD, NOMINAL, board_captures

F64 = torch.float64


# ----------------------------------------------------------------------------- solver
def test_levenberg_marquardt_and_covariance_match_linear_regression():
    g = torch.Generator().manual_seed(0)
    x = torch.linspace(0, 1, 50, dtype=F64)
    a = torch.stack([torch.ones_like(x), x], 1)
    y = a @ torch.tensor([1.0, -2.0], dtype=F64) + 0.01 * torch.randn(50, generator=g, dtype=F64)
    res = levenberg_marquardt(lambda p: a @ p - y, lambda p: a, torch.zeros(2, dtype=F64))
    ls = torch.linalg.lstsq(a, y[:, None]).solution[:, 0]
    assert res.converged and torch.allclose(res.x, ls, atol=1e-10)
    r = a @ res.x - y
    cov = covariance(a, float(r @ r))
    expected = float(r @ r) / 48 * torch.linalg.inv(a.T @ a)  # the textbook OLS covariance
    assert torch.allclose(cov, expected, rtol=1e-10)


def test_normal_inverse_keeps_weak_directions_of_mixed_units():
    """Columns in very different units with a weakly determined combination: the plain pseudo-inverse of J^T J
    (condition ~1e19) truncates it and under-states the variance; the column-normalised one matches the exact
    inverse computed in well-scaled coordinates."""
    g = torch.Generator().manual_seed(2)
    base = torch.randn(60, 3, generator=g, dtype=F64)
    base[:, 2] = base[:, 0] + 1e-3 * base[:, 2]  # columns 0 and 2 nearly the same direction
    units = torch.tensor([1e6, 1.0, 1e-3], dtype=F64)
    j = base * units
    exact = torch.linalg.inv(base.T @ base) / units[:, None] / units[None, :]
    got = normal_inverse(j)
    assert torch.allclose(got, exact, rtol=1e-6)
    plain = torch.linalg.pinv(j.T @ j, hermitian=True)
    assert float(plain[2, 2]) < 1e-3 * float(exact[2, 2])  # what the normalisation avoids


def test_unobservable_finds_a_pure_scale_and_a_dead_parameter():
    g = torch.Generator().manual_seed(1)
    j = torch.randn(40, 4, generator=g, dtype=F64)
    j[:, 2] = 3.0 * j[:, 0]  # a scale: column 2 reproduces column 0
    j[:, 3] = 0.0  # no effect at all
    removed = unobservable(j, [0, 1, 2, 3])
    assert 3 in removed and len(set(removed) & {0, 2}) == 1 and 1 not in removed
    assert unobservable(torch.randn(40, 3, generator=g, dtype=F64), [0, 1, 2]) == []


def test_parameter_vector_round_trip():
    rig = NOMINAL.replace(prism_tilt_deg=(0.1, -0.2, 0.3), distortion=(-0.05, 0.01, 0.0, 0.0, 0.0))
    assert vector_to_rig(rig_vector(rig), rig) == rig
    tol = tolerance_vector(rig, {"k1": 0.05, "roll_deg": 0.2})
    assert float(tol[NAMES.index("k1")]) == 0.05 and math.isclose(float(tol[NAMES.index("roll_deg")]),
                                                                   math.radians(0.2))
    assert math.isclose(float(tol[NAMES.index("focal_length_mm")]), 0.02 * rig.focal_length_mm)
    with pytest.raises(CalibrationError, match="unknown rig parameter.*valid: focal_length_mm"):
        tolerance_vector(rig, {"focal": 1.0})


def test_board_jacobian_matches_finite_differences(calibrated):
    rig, detections, _ = calibrated  # 3 of its views, seen through the distorting, misaligned rig that took them
    obs = gather_observations(detections[:3], BOARD)
    problem = BoardProblem(rig, obs, ["focal_length_mm", "k1", "alpha_deg", "roll_deg"], sigma_px=1.0)
    x = problem.x0.clone()
    j = problem.jacobian(x)
    for col in (0, 1, 2, 3, 4, 6 + 4, 4 + 6 * 2 + 5):
        h = 1e-6 * max(1.0, abs(float(x[col])))
        dx = torch.zeros_like(x)
        dx[col] = h
        fd = (problem.residuals(x + dx) - problem.residuals(x - dx)) / (2 * h)
        assert torch.allclose(j[:, col], fd, atol=1e-4 * float(fd.abs().max()) + 1e-7), col


# ----------------------------------------------------------------------------- calibration
# setup 1's narrow field of view (normalised radius <= 0.12, so k1 = 0.1 moves a corner pixel by ~0.1 px at quarter
# resolution) leaves k1 and T_o weakly determined by 8 quarter-resolution views: they must come back within their
# error bars, not necessarily closer; the roll is well determined
PERTURBED = {"prism_tilt_deg": (0.0, 0.0, 0.3), "distortion": (-0.09, 0.0, 0.0, 0.0, 0.0), "apex_distance_mm": 172.0}


def test_perturbed_parameters_are_recovered():
    """Three parameters of the rig perturbed at once (the roll, k1, the apex distance), every default-free
    parameter estimated from one calibration: each perturbed estimate within 3 standard errors of the truth, every
    estimate within 3.5, and the well-determined roll far closer than nominal."""
    true = NOMINAL.replace(**PERTURBED)
    cap = board_captures(true, 8, seed=3)
    result = calibrate_board(NOMINAL, list(cap.image), BOARD)
    truth = to_display(rig_vector(true))
    z = ((result.after - truth) / result.std_error)
    for name in ("roll_deg", "k1", "apex_distance_mm"):
        assert abs(float(z[NAMES.index(name)])) < 3, name
    roll = NAMES.index("roll_deg")
    assert abs(float(result.after[roll] - truth[roll])) < 0.35 * abs(float(result.before[roll] - truth[roll]))
    assert float(result.data_share[roll]) > 0.95
    assert bool((z[torch.isfinite(z)].abs() < 3.5).all()), z
    assert result.rms_px < 0.25 and set(result.free).isdisjoint(DEFAULT_FIXED)
    assert result.rig.prism_thickness_mm == NOMINAL.prism_thickness_mm
    assert "prism_offset_x_mm" in result.weak  # the views barely see d: the report says so


@pytest.fixture(scope="module")
def calibrated():
    """The true rig, the clean detections of its 9 views, and one calibration (p1 and p2 fixed, k2's tolerance
    given) of those views with view 3's left corners moved by a ramp of up to 1.5 px: an outlier view. The report,
    the plot and the outlier flag are checked on this one fit (instead of a clean fit and a second one with the
    outlier); the clean detections serve the tests of the initial poses, the Jacobian and a diverged fit."""
    true = NOMINAL.replace(prism_tilt_deg=(0.2, -0.3, 0.2), prism_offset_x_mm=0.3, alpha_deg=6.45,
                           distortion=(-0.06, 0.0, 0.0, 0.0, 0.0))
    cap = board_captures(true, 9, seed=4)
    dets = [detect_board(im, NOMINAL, BOARD) for im in cap.image]
    bad = list(dets)
    left = bad[3].left
    bad[3] = bad[3]._replace(left=left._replace(uv=left.uv + torch.tensor([1.5, -1.0], dtype=F64) *
                                                 torch.linspace(-1, 1, left.uv.shape[0], dtype=F64)[:, None]))
    return true, dets, calibrate_board(NOMINAL, bad, BOARD, fix=["p1", "p2"], tolerances={"k2": 0.05})


def test_result_report_and_plot(calibrated, tmp_path):
    true, dets, result = calibrated
    assert "p1" not in result.free and "k2" in result.free
    assert result.view_rms_px.shape == (9, 2) and result.poses.shape == (9, 6)
    assert result.residuals.shape == result.observations.uv.shape
    assert math.isclose(result.rms_px, float(result.residuals.pow(2).sum(1).mean().sqrt()))
    text = format_report(result, [f"img{i}.png" for i in range(9)])
    assert text.startswith("Calibrated from 9 views") and "img8.png" in text and "(fixed)" in text
    assert "prism_thickness_mm" in text and "roll_deg" in text
    # the depth uncertainty in one line: each depth's value, or one value once with its depths
    line = next(t for t in text.splitlines() if t.startswith("depth uncertainty from the calibration"))
    values = [f"{100 * float(v):.2f} %" for v in result.depth_uncertainty.relative_std]
    assert all(v in line for v in values) and (line.count(" % ") == 1) == (len(set(values)) == 1), line
    same = result._replace(depth_uncertainty=result.depth_uncertainty._replace(
        relative_std=result.depth_uncertainty.relative_std * 0 + 0.001))
    assert "0.10 % from " in format_report(same)
    plot_residuals(result, tmp_path / "r.png")
    assert (tmp_path / "r.png").stat().st_size > 10_000


def test_outlier_view_is_flagged_and_weighted_down(calibrated):
    """View 3 is an outlier after the first fit and stays one (its corners are wrong); the second fit weights it by
    the median view's RMS over its own, and the other views fit as clean views do."""
    true, dets, result = calibrated  # view 3's left corners are moved by up to 1.5 px
    assert result.outlier_views == (3,) and result.downweighted_views == (3,)
    text = format_report(result)
    assert "warning: view 3 has an outlier" in text and "view 3's error was an outlier after the first fit" in text
    clean = [result.observations.view == k for k in range(len(result.views)) if result.views[k] != 3]
    rms = result.residuals[torch.stack(clean).any(0)].pow(2).sum(1).mean().sqrt()
    assert float(rms) < 0.15  # the other views fit as well as clean views do


def test_initial_poses_triangulate_the_boards(calibrated):
    """Poses from corners triangulated with the true rig put the board's centre where the scene has it."""
    true, dets, result = calibrated
    obs = gather_observations(dets, BOARD)
    poses = initial_poses(true, obs)
    rot = kornia.geometry.conversions.axis_angle_to_rotation_matrix(poses[:, :3])
    centre = BOARD.points().mean(0)  # the inner corners' centroid is the board's centre
    placed = (rot @ centre).squeeze(-1) + poses[:, 3:]
    # the board plane's point is its pattern's corner: the centre is half the 5 x 8 squares of 6 mm further
    truth = torch.stack([s.surfaces[0].point + s.surfaces[0].u_axis * 15.0 + s.surfaces[0].v_axis * 24.0
                         for s in calibration_views(9, 4)])
    err = (placed - truth).norm(dim=1)
    assert err.max() < 0.005 * float(truth[:, 2].min()), err


def test_calibration_errors():
    with pytest.raises(CalibrationError, match="too few views: 2 captures, need at least 3"):
        calibrate_board(NOMINAL, [torch.zeros(1, 192, 256)] * 2, BOARD)
    with pytest.raises(CalibrationError, match="found in both halves of 0 of 3 views, need 3"):
        calibrate_board(NOMINAL, [torch.zeros(1, 192, 256)] * 3, BOARD)
    with pytest.raises(CalibrationError, match="image is 10x10 px"):
        calibrate_board(NOMINAL, [torch.zeros(1, 10, 10)] * 3, BOARD)
    with pytest.raises(CalibrationError, match="unknown rig parameter"):
        calibrate_board(NOMINAL, [torch.zeros(1, 192, 256)] * 3, BOARD, fix=["zoom"])


def test_diverged_fit_is_an_error(calibrated):
    """A wrong nominal rig (setup 1's prism called 4.4 deg) cannot explain the corners: a clear error."""
    true, dets, result = calibrated
    wrong = NOMINAL.replace(alpha_deg=4.4)
    with pytest.raises(CalibrationError, match="diverged|do not triangulate"):
        calibrate_board(wrong, dets, BOARD, max_iterations=3, max_rms_px=0.5)


def test_review_guards():
    """Bad inputs fail with clear errors instead of crashing or being fitted silently."""
    res = levenberg_marquardt(lambda x: x * float("nan"), lambda x: torch.eye(2, dtype=F64),
                              torch.ones(2, dtype=F64))
    assert not res.converged and "not finite" in res.message
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(CalibrationError, match="tolerances must be positive"):
            tolerance_vector(NOMINAL, {"k1": bad})
    assert math.isinf(float(tolerance_vector(NOMINAL, {"k1": float("inf")})[NAMES.index("k1")]))
    with pytest.raises(CalibrationError, match="captures must be a list of images"):
        calibrate_board(NOMINAL, torch.zeros(3, 192, 256), BOARD)
    src = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    r, t = rigid_fit(src, src + 1.0)  # float32 in, float32 out
    assert r.dtype == torch.float32 and torch.allclose(t, torch.ones(3))
    with pytest.raises(CalibrationError, match="N >= 3"):
        rigid_fit(src[:2], src[:2])
