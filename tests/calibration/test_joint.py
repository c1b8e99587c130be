"""Joint calibration (:mod:`prismstereo.calibration.joint`): board views and textured scenes in one bundle
adjustment, what each input contributed, scenes that disagree, and the errors."""

import pytest
import torch

from prismstereo import CalibrationError
from prismstereo.calibration import NAMES, calibrate_joint, detect_board, find_correspondences
from prismstereo.calibration.board import BoardProblem, gather_observations
from prismstereo.calibration.joint import JointProblem
from prismstereo.calibration.parameters import rig_vector, to_display, tolerance_vector
from prismstereo.calibration.report import format_report
from prismstereo.calibration.selfcal import SelfProblem
from prismstereo.synthetic import ImageFormation, render, slanted_plane, sphere_scene, step_scene
from tests.calibration.conftest import BOARD, NOMINAL, board_captures

F64 = torch.float64
# the principal point, k1, the prism's offset and angle, the apex distance: what the rig changes
TRUE = NOMINAL.replace(principal_point=(NOMINAL.principal_point[0] + 1.0, NOMINAL.principal_point[1] - 0.5),
                       distortion=(-0.1, 0.0, 0.0, 0.0, 0.0), prism_offset_x_mm=0.3, alpha_deg=6.45,
                       apex_distance_mm=171.0)


@pytest.fixture(scope="module")
def inputs():
    """Six board views' detections (view 2's left corners moved by a ramp of up to 1.5 px: an outlier view) and three
    scenes' matches through TRUE, and a fourth scene through another rig (its prism rolled by 1 deg: a capture that
    disagrees with the others)."""
    boards = [detect_board(im, NOMINAL, BOARD) for im in board_captures(TRUE, 6, seed=5).image]
    left = boards[2].left
    ramp = torch.tensor([1.5, -1.0], dtype=F64) * torch.linspace(-1, 1, left.uv.shape[0], dtype=F64)[:, None]
    boards[2] = boards[2]._replace(left=left._replace(uv=left.uv + ramp))
    scenes = [slanted_plane(TRUE, 600.0, 20.0, seed=1), step_scene(TRUE, 500.0, 800.0, seed=2),
              sphere_scene(TRUE, 650.0, 60.0, 900.0, seed=3)]
    caps = render(TRUE, scenes, ImageFormation(supersample=2, noise_sigma=2 / 255, seed=6)).image
    other = render(TRUE.replace(prism_tilt_deg=(0.0, 0.0, 1.0)), slanted_plane(TRUE, 600.0, 20.0, seed=4),
                   ImageFormation(supersample=2, noise_sigma=2 / 255, seed=7)).image[0]
    matches = [find_correspondences(im, NOMINAL, view=k) for k, im in enumerate([*caps, other])]
    return boards, matches


@pytest.fixture(scope="module")
def joint(inputs):
    """One joint calibration of the six views and the four scenes: the fourth scene is left out after the first
    fit, and the result is the second fit's."""
    boards, matches = inputs
    return calibrate_joint(NOMINAL, boards, BOARD, matches, max_correspondences=200)


def test_joint_calibration_recovers_the_rig_and_says_what_each_input_gave(joint):
    """Every estimate within 3.5 standard errors of the truth; the boards and the scenes together know every
    parameter at least as well as either alone; the scenes add what the epipolar curves show (the distortion, the
    prism's roll and tilts), and only the boards give the scale (the apex distance)."""
    truth = to_display(rig_vector(TRUE))
    z = (joint.after - truth) / joint.std_error
    assert bool((z[torch.isfinite(z)].abs() < 3.5).all()), z
    found = joint.joint.contributions
    assert found.names == ("boards", "scenes", "both")
    free = torch.tensor([NAMES.index(n) for n in joint.free])
    boards, scenes, both = found.std_error[:, free]
    assert bool((both <= boards * (1 + 1e-6)).all() and (both <= scenes * (1 + 1e-6)).all())
    torch.testing.assert_close(found.std_error[2], joint.std_error, equal_nan=True)
    gain = {n: float(found.std_error[2, NAMES.index(n)] / found.std_error[0, NAMES.index(n)])
            for n in ("k1", "roll_deg", "tilt_x_deg", "tilt_y_deg")}
    # measured 0.73 for k1, 0.89 for the roll and tilts with 300 matches of 3 scenes beside 6 views
    assert gain["k1"] < 0.8 and all(g < 0.93 for g in gain.values()), gain
    t_o = NAMES.index("apex_distance_mm")
    assert float(found.std_error[0, t_o]) < 0.5 * float(found.std_error[1, t_o])
    assert len(joint.joint.predicted) == 3 and joint.joint.scenes == (0, 1, 2)
    assert 0.05 < joint.joint.scene_sigma_px < 1.0
    assert joint.rms_px < 0.25 and joint.observations.uv.shape[0] == joint.residuals.shape[0]


def test_the_report_names_each_input_set(joint):
    text = format_report(joint, None, ["plane.png", "step.png", "sphere.png", "other.png"])
    assert "what each input determines" in text and "depth uncertainty each set predicts" in text
    assert "plane.png" in text and "scenes:" in text
    for name in joint.weak:
        assert f"  {name}: " in text  # what would determine it


def test_a_scene_that_disagrees_is_left_out_and_an_outlier_view_weighted_down(joint):
    assert joint.joint.outlier_scenes == (3,) and 3 not in joint.joint.scenes
    assert joint.downweighted_views == (2,)
    text = format_report(joint, None, ["a", "b", "c", "other.png"])
    assert "warning: scene other.png was left out" in text and "view 2's error was an outlier after the first" in text


def test_joint_problem_stacks_its_parts(inputs):
    """x = [rig, board poses, match depths]; each part's rows touch the rig and its own blocks only."""
    boards, matches = inputs
    names, tol = ["k1", "roll_deg"], tolerance_vector(NOMINAL)
    parts = [BoardProblem(NOMINAL, gather_observations(boards, BOARD), names, tol), SelfProblem(NOMINAL, matches[0],
                                                                                                names, tol)]
    problem = JointProblem(parts)
    sizes = [p.x0.numel() - 2 for p in parts]
    assert problem.x0.numel() == 2 + sum(sizes) and problem.sizes == sizes
    j = problem.jacobian(problem.x0)
    rows = 2 * parts[0].observed.shape[0]
    assert j.shape == (2 * problem.observed.shape[0] + 2, problem.x0.numel())
    assert bool((j[:rows, 2 + sizes[0]:] == 0).all()) and bool((j[rows:-2, 2:2 + sizes[0]] == 0).all())
    res = problem.residuals(problem.x0)
    torch.testing.assert_close(res[:rows], parts[0].residuals(parts[0].x0)[:rows])
    with pytest.raises(CalibrationError, match="must share the rig, free parameters and priors"):
        JointProblem([parts[0], SelfProblem(NOMINAL, matches[0], ["k1"], tol)])
    with pytest.raises(CalibrationError, match="at least one part"):
        JointProblem([])


def test_joint_calibration_errors(inputs):
    boards, matches = inputs
    with pytest.raises(CalibrationError, match="no scene captures: pass the boards alone to calibrate_board"):
        calibrate_joint(NOMINAL, boards, BOARD, [])
    with pytest.raises(CalibrationError, match="scenes must be a list of captures .* got one array"):
        calibrate_joint(NOMINAL, boards, BOARD, torch.zeros(1, 192, 256))
    blank = torch.full((1, 192, 256), 0.5, dtype=F64)
    with pytest.raises(CalibrationError, match="the scenes need texture seen by both halves"):
        calibrate_joint(NOMINAL, boards, BOARD, [blank])
    with pytest.raises(CalibrationError, match="too few views"):
        calibrate_joint(NOMINAL, boards[:2], BOARD, matches[:1])
    one_half = [d._replace(right=None) for d in boards[:4]] + boards[4:]  # the board in the left half only
    with pytest.raises(CalibrationError, match=r"found in both halves of 2 of 6 views, need 3 .*0: left yes, right no"):
        calibrate_joint(NOMINAL, one_half, BOARD, matches[:1])
