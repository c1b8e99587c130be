"""Calibrate a rig from captures of a board: detection, observability, bundle adjustment, statistics.

:func:`calibrate_board` is the procedure a user runs on a bench: captures of a checkerboard or ChArUco board
through the prism at several poses, the nominal rig file, and which parameters to hold fixed. It returns the
calibrated rig with the report OpenCV's ``calibrateCameraExtended`` gives (RMS and per-view reprojection
error, standard errors of every estimated parameter) plus the before/after values and outlier views.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
import torch
from tqdm.auto import tqdm

from prismstereo.calibration.board import BoardProblem, Observations, gather_observations
from prismstereo.calibration.parameters import (
    NAMES,
    check_names,
    rig_vector,
    to_display,
    tolerance_vector,
    vector_to_rig,
)
from prismstereo.calibration.problem import RigProblem
from prismstereo.calibration.solver import levenberg_marquardt, normal_inverse
from prismstereo.calibration.targets import Board, CornerMethod, ViewDetection, detect_board, found_instead
from prismstereo.calibration.uncertainty import DepthUncertainty, depth_uncertainty
from prismstereo.errors import CalibrationError, RigError
from prismstereo.geometry.optics import check_rig_images
from prismstereo.geometry.rig import BiPrismRig

__all__ = ["CalibrationResult", "DEFAULT_FIXED", "SolvedProblem", "board_observations", "calibrate_board",
           "solve_rig_problem", "view_depth_uncertainty", "view_outliers", "view_weights"]

# Held at their nominal values unless freed: the prism's thickness trades against its distance (both move the
# virtual centres along z) and is known from the part's drawing; k3 matters only for wide-angle lenses (OpenCV's
# usual CALIB_FIX_K3).
DEFAULT_FIXED: tuple[str, ...] = ("prism_thickness_mm", "k3")


class CalibrationResult(NamedTuple):
    """A calibration's outcome.

    Attributes:
        rig: the calibrated rig.
        nominal: the rig it started from.
        free: names of the estimated rig parameters.
        data_share: (16,) how much of each estimate came from the views rather than the prior,
            1 - posterior variance / prior variance (NaN for parameters not estimated).
        weak: names of estimated parameters with data_share < 0.5: the views barely determine them, their
            values stay near nominal by their tolerance.
        unobservable: names the data cannot determine at all (self-calibration: e.g. a length scale), held at
            their nominal values; empty for a target calibration.
        sigma_px: the corner noise estimated from the residuals (px per coordinate).
        before: (16,) nominal values of :data:`~prismstereo.calibration.parameters.NAMES` (reported units).
        after: (16,) calibrated values.
        std_error: (16,) standard errors (NaN for parameters not estimated).
        covariance: (16, 16) covariance of the rig vector (internal units, angles in rad): the fit's for the
            estimated parameters, the prior tolerance squared for the ones held fixed (they are known only to
            their tolerance), no correlation between the two groups.
        rms_px: RMS reprojection error over every corner (px).
        depth_uncertainty: the calibration's own depth uncertainty (the covariance propagated to triangulated
            depth, :func:`~prismstereo.calibration.uncertainty.depth_uncertainty`) at the nearest, median and
            farthest depth of the views.
        view_rms_px: (V, 2) RMS per kept view and half (left, right), px.
        views: indices of the kept views among the inputs.
        outlier_views: indices (among the inputs) of views whose error is an outlier.
        residuals: (M, 2) projection minus detection per corner (px).
        observations: the corners (:class:`~prismstereo.calibration.board.Observations`).
        poses: (V, 6) board poses (axis-angle rad, translation mm) of the kept views.
        iterations: solver iterations.
        message: why the solver stopped.
        joint: with scenes beside the boards (:func:`~prismstereo.calibration.joint.calibrate_joint`), what each
            input contributed and the scenes' fit (:class:`~prismstereo.calibration.joint.JointReport`); else None.
        downweighted_views: indices of views whose error was an outlier after a first fit, weighted in a second
            one by the median view's RMS over theirs (:func:`view_weights`).
    """

    rig: BiPrismRig
    nominal: BiPrismRig
    free: tuple[str, ...]
    data_share: torch.Tensor
    weak: tuple[str, ...]
    unobservable: tuple[str, ...]
    sigma_px: float
    before: torch.Tensor
    after: torch.Tensor
    std_error: torch.Tensor
    covariance: torch.Tensor
    rms_px: float
    depth_uncertainty: DepthUncertainty
    view_rms_px: torch.Tensor
    views: tuple[int, ...]
    outlier_views: tuple[int, ...]
    residuals: torch.Tensor
    observations: Observations
    poses: torch.Tensor
    iterations: int
    message: str
    joint: Any = None  # a JointReport (prismstereo.calibration.joint, which builds on this module)
    downweighted_views: tuple[int, ...] = ()


def view_outliers(view_rms: torch.Tensor, views: Sequence[int], factor: float = 3.0,
                  floor_px: float = 0.1) -> tuple[int, ...]:
    """Views whose RMS (over both halves) exceeds ``factor`` x the median view's and ``floor_px``.

    Example:
        >>> view_outliers(torch.tensor([[0.1, 0.1], [0.1, 0.12], [0.9, 1.0]]), [0, 1, 2])
        (2,)
    """
    per_view = view_rms.pow(2).nan_to_num(0.0).mean(dim=1).sqrt()
    if per_view.numel() < 3:
        return ()
    med = float(per_view.median())
    return tuple(views[i] for i in range(len(views)) if float(per_view[i]) > max(factor * med, floor_px))


def view_depth_uncertainty(rig: BiPrismRig, covariance: torch.Tensor, depths: torch.Tensor) -> DepthUncertainty:
    """:func:`~prismstereo.calibration.uncertainty.depth_uncertainty` at the smallest, median and largest of ``depths``
    (the views' depths, mm).

    Example:
        >>> view_depth_uncertainty(thesis_setup1(), torch.zeros(16, 16, dtype=torch.float64),
        ...                        torch.tensor([500.0, 700.0])).relative_std
        tensor([0., 0., 0.], dtype=torch.float64)
    """
    z = depths.detach().to(torch.float64)
    return depth_uncertainty(rig, covariance, [float(z.min()), float(z.median()), float(z.max())])


def _board_depths(problem: BoardProblem, x: torch.Tensor) -> torch.Tensor:
    """(V,) depth (mm) of each posed board's centre."""
    # kornia imported where used: a cached graph's depth run never loads it
    from kornia.geometry.conversions import axis_angle_to_rotation_matrix

    poses = problem.blocks(x)
    rot = axis_angle_to_rotation_matrix(poses[:, :3])
    return (rot @ problem.obs.points.mean(0).to(poses))[:, 2] + poses[:, 5]


def _per_view_rms(res: torch.Tensor, obs: Observations) -> torch.Tensor:
    out = torch.full((len(obs.views), 2), float("nan"), dtype=torch.float64)
    sq = res.pow(2).sum(dim=1)
    for k in range(len(obs.views)):
        for j, mask in enumerate((obs.left, ~obs.left)):
            sel = (obs.view == k) & mask & torch.isfinite(sq)
            if bool(sel.any()):
                out[k, j] = sq[sel].mean().sqrt()
    return out


def _not_found(rig: BiPrismRig, board: Board, captures: Sequence, detections: Sequence[ViewDetection], found: int,
               needed: int) -> str:
    """The error of a board found in too few views: per view which halves show it, and what the others show instead
    (:func:`~prismstereo.calibration.targets.found_instead`)."""
    views = [f"{i}: left {'yes' if d.left is not None else 'no'}, right {'yes' if d.right is not None else 'no'}"
             for i, d in enumerate(detections)]
    instead = [found_instead(c, rig, board) for c, d in zip(captures, detections, strict=True)
               if not isinstance(c, ViewDetection) and (d.left is None or d.right is None)]
    counts = Counter(text for text in instead if text)
    hint = "".join(f"; found instead in {n} view{'s' * (n > 1)}: {text} (is the target's size right?)"
                   for text, n in counts.most_common(2))
    return (f"board {board.describe()} found in both halves of {found} of {len(detections)} views, need {needed}"
            f"{hint} ({'; '.join(views)})")


def board_observations(rig: BiPrismRig, captures: Sequence[torch.Tensor | np.ndarray | ViewDetection], board: Board,
                       *, min_views: int = 3, corners: CornerMethod = "symmetric",
                       progress: bool = False) -> Observations:
    """The corners of ``board`` found in both halves of the captures (images or their detections).

    Raises:
        CalibrationError: fewer than ``min_views`` captures with the board in both halves (saying what was found
            instead), images of the wrong size.

    Example:
        >>> board_observations(thesis_setup1(), images, parse_target("checkerboard:7x5:5"))  # doctest: +SKIP
    """
    if len(captures) < min_views:
        raise CalibrationError(f"too few views: {len(captures)} captures, need at least {min_views}")
    detections = [c if isinstance(c, ViewDetection) else detect_board(c, rig, board, corners=corners)
                  for c in tqdm(captures, desc="detect", disable=None if progress else True, leave=False)]
    obs = gather_observations(detections, board)
    if len(obs.views) < min_views:
        raise CalibrationError(_not_found(rig, board, captures, detections, len(obs.views), min_views))
    return obs


def calibrate_board(
    rig: BiPrismRig,
    captures: Sequence[torch.Tensor | np.ndarray | ViewDetection],
    board: Board,
    *,
    fix: Sequence[str] = (),
    free: Sequence[str] = (),
    min_views: int = 3,
    max_iterations: int = 100,
    max_rms_px: float = 2.0,
    tolerances: dict[str, float] | None = None,
    corners: CornerMethod = "symmetric",
    progress: bool = False,
) -> CalibrationResult:
    """Calibrate ``rig`` from captures of ``board`` through the prism (target-based, bundle adjustment).

    Args:
        rig: the nominal rig: the start of every parameter and the value of every fixed one.
        captures: images ((C, H, W) / (H, W) float tensors in [0, 1] or uint8 arrays) or their
            :class:`~prismstereo.calibration.targets.ViewDetection`.
        board: the target.
        fix: rig parameters to hold at their nominal values, besides :data:`DEFAULT_FIXED`.
        free: parameters of :data:`DEFAULT_FIXED` to estimate after all.
        min_views: views with the board in both halves required.
        max_iterations: Levenberg-Marquardt iterations at most.
        max_rms_px: a final RMS above this is a diverged fit (error).
        tolerances: 1-sigma priors overriding :data:`~prismstereo.calibration.parameters.TOLERANCES` (reported
            units, absolute; ``inf`` for none): how well the nominal rig is known.
        corners: sub-pixel corner method of :func:`~prismstereo.calibration.targets.detect_board` for images
            ('symmetric' or 'opencv').
        progress: progress bars for detection and the fit (where stderr is a terminal).

    Returns:
        CalibrationResult.

    Raises:
        CalibrationError: fewer than ``min_views`` captures, the board not found in both halves of enough views,
            images of the wrong size, unknown parameter names, or a fit that diverged (RMS > ``max_rms_px``,
            or a rig the optics reject).

    Example:
        >>> from prismstereo.calibration import parse_target
        >>> calibrate_board(thesis_setup1(), [], parse_target("checkerboard:4x7:6"))
        Traceback (most recent call last):
        ...
        prismstereo.errors.CalibrationError: too few views: 0 captures, need at least 3
    """
    if isinstance(captures, (torch.Tensor, np.ndarray)):
        raise CalibrationError("captures must be a list of images (one tensor or array per capture), got one "
                               f"{type(captures).__name__}")
    fixed = set(check_names(fix)) | (set(DEFAULT_FIXED) - set(check_names(free)))
    obs = board_observations(rig, captures, board, min_views=min_views, corners=corners, progress=progress)
    names, tol = [n for n in NAMES if n not in fixed], tolerance_vector(rig, tolerances)
    problem = BoardProblem(rig, obs, names, tol, sigma_px=0.1)
    solved = solve_rig_problem(problem, max_iterations=max_iterations, max_rms_px=max_rms_px, progress=progress)
    weight, weighted = view_weights(solved.residuals, obs)
    if weighted:  # a robust refit from the first fit, the priors still on the nominal rig
        problem = BoardProblem(solved.rig, obs, names, tol, sigma_px=problem.sigma_px)
        problem.base, problem.weight = rig_vector(rig), weight
        solved = solve_rig_problem(problem, max_iterations=max_iterations, max_rms_px=max_rms_px, progress=progress)
    res = solved.residuals
    view_rms = _per_view_rms(res, obs)
    return CalibrationResult(
        rig=solved.rig, nominal=rig, free=problem.free, data_share=solved.data_share, weak=solved.weak,
        unobservable=(), sigma_px=problem.sigma_px, before=to_display(rig_vector(rig)), after=solved.after,
        std_error=solved.std_error, covariance=solved.covariance, rms_px=solved.rms_px,
        depth_uncertainty=view_depth_uncertainty(solved.rig, solved.covariance, _board_depths(problem, solved.x)),
        view_rms_px=view_rms,
        views=obs.views,
        outlier_views=view_outliers(view_rms, obs.views), residuals=res, observations=obs,
        poses=problem.blocks(solved.x), iterations=solved.iterations, message=solved.message,
        downweighted_views=weighted,
    )


def view_weights(residuals: torch.Tensor, obs: Observations) -> tuple[torch.Tensor, tuple[int, ...]]:
    """Each corner's weight for a robust refit: the median view's RMS over its view's for the views whose error is
    an outlier (:func:`view_outliers`: a corner misdetected, a board bent or moved during the capture), else 1; and
    those views (input indices).

    Example:
        >>> weight, views = view_weights(result.residuals, result.observations)  # doctest: +SKIP
    """
    halves = _per_view_rms(residuals, obs)
    per_view = halves.pow(2).nan_to_num(0.0).mean(dim=1).sqrt()
    views = view_outliers(halves, obs.views)
    weight = torch.ones(residuals.shape[0], dtype=torch.float64)
    median = per_view.median()
    for k, v in enumerate(obs.views):
        if v in views:
            weight[obs.view == k] = median / per_view[k]
    return weight, views


class SolvedProblem(NamedTuple):
    """:func:`solve_rig_problem`'s result.

    Attributes:
        x: the solution vector.
        rig: the calibrated rig.
        residuals: (M, 2) predicted - observed pixels (NaN for observations left out: not projectable through
            the nominal rig).
        rms_px: RMS of the residuals' lengths (px).
        after: (16,) the rig's values (reported units).
        std_error: (16,) standard errors (reported units, NaN where not estimated).
        covariance: (16, 16) covariance of the rig vector (see :class:`CalibrationResult`).
        data_share: (16,) 1 - posterior / prior variance (NaN where not estimated).
        weak: estimated names with data_share < 0.5.
        iterations: solver iterations over all passes.
        message: why the last pass stopped.
    """

    x: torch.Tensor
    rig: BiPrismRig
    residuals: torch.Tensor
    rms_px: float
    after: torch.Tensor
    std_error: torch.Tensor
    covariance: torch.Tensor
    data_share: torch.Tensor
    weak: tuple[str, ...]
    iterations: int
    message: str


def solve_rig_problem(problem: RigProblem, *, max_iterations: int = 100, max_rms_px: float = 2.0,
                      progress: bool = False) -> SolvedProblem:
    """Solve a calibration problem: Levenberg-Marquardt, re-weighted until ``problem.sigma_px`` matches the noise the
    residuals show (it sets the views' weight against the priors), then the statistics.

    Raises:
        CalibrationError: RMS > ``max_rms_px`` or a rig the optics reject (a diverged fit).

    Example:
        >>> solve_rig_problem(problem)  # doctest: +SKIP
    """
    _, valid = problem.projections(problem.x0)
    problem.active = valid.clone()
    dropped = int((~valid).sum())
    if dropped > valid.numel() // 2:
        raise CalibrationError(f"{dropped} of {valid.numel()} observations cannot be projected through the nominal rig "
                               "(is the rig file the right one?)")
    x, iterations, message = problem.x0, 0, ""
    for _ in range(3):
        fit = levenberg_marquardt(problem.residuals, problem.jacobian, x, max_iterations=max_iterations,
                                  progress=progress, description="calibrate")
        x, iterations, message = fit.x, iterations + fit.iterations, fit.message
        if not fit.converged and not math.isfinite(fit.cost):
            raise CalibrationError(f"the fit diverged: {fit.message}")
        if problem.reweight(x):  # the observations' weight against the priors: the noise they show
            break
    res = problem.projections(x)[0] - problem.observed
    res = torch.where(problem.active.unsqueeze(-1), res, torch.full_like(res, float("nan")))
    rms = float(res.pow(2).sum(dim=1).nanmean().sqrt())
    if dropped:
        message += f"; {dropped} observations not projectable through the nominal rig were left out"
    if not rms <= max_rms_px:
        raise CalibrationError(f"the fit diverged: RMS reprojection error {rms:.3g} px > {max_rms_px} px after "
                               f"{iterations} iterations ({message}); check the nominal rig, the target and the images")
    full = problem.full_vector(x)
    try:
        calibrated = vector_to_rig(full, problem.rig)
        check_rig_images(calibrated)  # once, on the result: the steps build no rigs
    except RigError as exc:
        raise CalibrationError(f"the fit diverged to an invalid rig: {exc}") from exc
    j = problem.jacobian(x)
    cov_free = normal_inverse(j)[: problem.num_rig, : problem.num_rig]  # residuals are already / sigma
    var = cov_free.diagonal().clamp_min(0)
    prior_var = problem.tolerance.pow(2).nan_to_num(posinf=0.0)  # no prior (inf): no variance assumed
    cov = torch.diag(prior_var)
    cov[problem.index[:, None], problem.index[None, :]] = cov_free
    std = torch.full((len(NAMES),), float("nan"), dtype=torch.float64)
    std[problem.index] = var.sqrt()
    share = torch.full((len(NAMES),), float("nan"), dtype=torch.float64)
    share[problem.index] = (1.0 - var * problem.prior_weight.pow(2)).clamp(0.0, 1.0)
    weak = tuple(n for n in problem.free if float(share[NAMES.index(n)]) < 0.5)
    return SolvedProblem(x, calibrated, res, rms, to_display(full.detach()), to_display(std), cov, share, weak,
                         iterations, message)
