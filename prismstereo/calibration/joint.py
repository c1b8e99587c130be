"""Joint calibration: board views and ordinary scenes in one bundle adjustment.

A small board seen by both halves only in their common field of view leaves the distortion, the principal point
and the prism's offset weakly determined. A textured scene adds what the epipolar curves show (every matched pixel
pair lies on an exact epipolar curve of the true rig, :mod:`~prismstereo.calibration.selfcal`): the distortion, the
prism's roll and tilts. The board fixes the metric scale and the focal length, which scenes cannot: the two virtual
cameras are nearly parallel, so their epipolar geometry hardly depends on f (``docs/usage.md`` has the measured
share of each). :class:`JointProblem` stacks the two problems over one set of free rig parameters:

- x = [free rig values, board poses (V, 6), match depths (N, 1)];
- residuals: each part's observations over its own noise (board corners ~0.1 px, SIFT matches ~0.3 px, each
  re-estimated from its residuals: :meth:`JointProblem.reweight`), then one prior row per free rig parameter.

What each input contributed is read from the Fisher information at the solution (:func:`contributions`): the
rig's covariance from the boards' rows alone, from the scenes' alone, and from both (each with the priors).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import torch

from prismstereo.calibration.board import BoardProblem
from prismstereo.calibration.fit import (
    DEFAULT_FIXED,
    CalibrationResult,
    _board_depths,
    _per_view_rms,
    board_observations,
    solve_rig_problem,
    view_depth_uncertainty,
    view_outliers,
    view_weights,
)
from prismstereo.calibration.parameters import NAMES, check_names, rig_vector, to_display, tolerance_vector
from prismstereo.calibration.problem import RigProblem
from prismstereo.calibration.selfcal import Correspondences, SelfProblem, _matches
from prismstereo.calibration.solver import normal_inverse
from prismstereo.calibration.targets import Board, CornerMethod, ViewDetection
from prismstereo.calibration.uncertainty import DepthUncertainty
from prismstereo.errors import CalibrationError
from prismstereo.geometry.rig import BiPrismRig

__all__ = ["Contributions", "JointProblem", "JointReport", "calibrate_joint", "contributions"]

F64 = torch.float64


class JointProblem(RigProblem):
    """Several calibration problems over the same free rig parameters, solved as one.

    Args:
        parts: the problems (a :class:`~prismstereo.calibration.board.BoardProblem`, a
            :class:`~prismstereo.calibration.selfcal.SelfProblem`), built from the same rig, free names and
            tolerances; each keeps its own noise ``sigma_px``.

    Raises:
        CalibrationError: no parts, or parts of different rigs, free parameters or tolerances.

    Example:
        >>> JointProblem([board_problem, self_problem]).num_rig  # doctest: +SKIP
        12
    """

    def __init__(self, parts: Sequence[RigProblem]) -> None:
        if not parts:
            raise CalibrationError("a joint problem needs at least one part")
        first = parts[0]
        for part in parts[1:]:
            if part.rig != first.rig or part.free != first.free or not torch.equal(part.tolerance, first.tolerance):
                raise CalibrationError("the parts of a joint problem must share the rig, free parameters and priors")
        self.parts = tuple(parts)
        self.rig, self.free, self.index, self.base = first.rig, first.free, first.index, first.base
        self.tolerance, self.prior_weight = first.tolerance, first.prior_weight
        p = first.num_rig
        self.sizes = [part.x0.numel() - p for part in parts]  # each part's block unknowns
        self.x0 = torch.cat([first.x0[:p], *(part.x0[p:] for part in parts)])
        self.rows = [part.observed.shape[0] for part in parts]  # each part's observations

    @property
    def num_rig(self) -> int:
        """Number of free rig parameters (the first entries of x)."""
        return len(self.free)

    @property
    def sigma_px(self) -> float:
        """The first part's noise (px per coordinate): the board corners' in a board-and-scenes problem."""
        return self.parts[0].sigma_px

    @property
    def observed(self) -> torch.Tensor:
        """(M, 2) every part's observed pixels, part after part."""
        return torch.cat([part.observed for part in self.parts])

    @property
    def weight(self) -> torch.Tensor:
        """(M,) each observation's weight (the parts' weights, part after part)."""
        return torch.cat([part.weight for part in self.parts])

    @weight.setter
    def weight(self, value: torch.Tensor) -> None:
        for part, w in zip(self.parts, value.split(self.rows), strict=True):
            part.weight = w.clone()

    @property
    def active(self) -> torch.Tensor:
        """(M,) which observations take part (the parts' masks, part after part)."""
        return torch.cat([part.active for part in self.parts])

    @active.setter
    def active(self, value: torch.Tensor) -> None:
        for part, mask in zip(self.parts, value.split(self.rows), strict=True):
            part.active = mask.clone()

    def part_x(self, x: torch.Tensor, k: int) -> torch.Tensor:
        """Part ``k``'s own x: the rig values and its block unknowns."""
        p, start = self.num_rig, self.num_rig + sum(self.sizes[:k])
        return torch.cat([x[:p], x[start:start + self.sizes[k]]])

    def full_vector(self, x: torch.Tensor) -> torch.Tensor:
        """(16,) rig vector with the free entries taken from x."""
        return self.parts[0].full_vector(x[: self.num_rig])

    def projections(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(M, 2) predicted pixels and (M,) validity, part after part."""
        out = [part.projections(self.part_x(x, k)) for k, part in enumerate(self.parts)]
        return torch.cat([uv for uv, _ in out]), torch.cat([valid for _, valid in out])

    def residuals(self, x: torch.Tensor) -> torch.Tensor:
        """(2M + P,) every part's data rows (each over its own noise), then the P prior rows."""
        data = [part.residuals(self.part_x(x, k))[: 2 * m] for k, (part, m) in enumerate(zip(self.parts, self.rows,
                                                                                               strict=True))]
        return torch.cat([*data, self.prior_rows(x)[0]])

    def jacobian(self, x: torch.Tensor) -> torch.Tensor:
        """(2M + P, n) Jacobian of :meth:`residuals`: each part's rows on the rig columns and its own blocks."""
        p, m = self.num_rig, 2 * sum(self.rows)
        full = torch.zeros(m + p, x.numel(), dtype=x.dtype)
        row, col = 0, p
        for k, part in enumerate(self.parts):
            j = part.jacobian(self.part_x(x, k))[: 2 * self.rows[k]]
            full[row:row + j.shape[0], :p] = j[:, :p]
            full[row:row + j.shape[0], col:col + self.sizes[k]] = j[:, p:]
            row, col = row + j.shape[0], col + self.sizes[k]
        full[m:] = self.prior_rows(x)[1]
        return full

    def reweight(self, x: torch.Tensor) -> bool:
        """Each part's noise re-estimated from its own residuals at x; whether every one had settled (within
        20 % of the noise it was weighted with)."""
        share = self.num_rig / max(1, sum(self.rows))  # the rig's unknowns, spread over the observations
        settled = True
        for k, part in enumerate(self.parts):
            settled &= part.reweight(self.part_x(x, k), rig_unknowns=share * self.rows[k])
        return settled


class Contributions(NamedTuple):
    """What each input set determines, from the Fisher information at the solution.

    Attributes:
        names: the sets ('boards', 'scenes', 'both').
        std_error: (S, 16) standard error of every rig parameter (reported units) from each set's rows and the
            priors (NaN where not estimated; a parameter a set does not see keeps its prior's).
        covariance: (S, 16, 16) the rig vector's covariance from each set (internal units; fixed parameters:
            their prior variance), as :attr:`~prismstereo.calibration.fit.CalibrationResult.covariance`.
    """

    names: tuple[str, ...]
    std_error: torch.Tensor
    covariance: torch.Tensor


def contributions(problem: JointProblem, x: torch.Tensor, names: Sequence[str]) -> Contributions:
    """The rig's uncertainty from each part alone (with the priors) and from all of them, at ``x``.

    Args:
        problem: the solved joint problem.
        x: its solution.
        names: a name per part (e.g. 'boards', 'scenes'); 'both' is added for all of them together.

    Returns:
        Contributions.

    Example:
        >>> contributions(problem, solved.x, ["boards", "scenes"]).names  # doctest: +SKIP
        ('boards', 'scenes', 'both')
    """
    if len(names) != len(problem.parts):
        raise CalibrationError(f"one name per part: {len(problem.parts)} parts, {len(names)} names")
    j = problem.jacobian(x)
    p, m = problem.num_rig, 2 * sum(problem.rows)
    prior_rows = torch.arange(m, m + p)
    sets, covs, stds = [], [], []
    row, col = 0, p
    selections = []
    for k in range(len(problem.parts)):
        rows = torch.cat([torch.arange(row, row + 2 * problem.rows[k]), prior_rows])
        cols = torch.cat([torch.arange(p), torch.arange(col, col + problem.sizes[k])])
        selections.append((rows, cols))
        row, col = row + 2 * problem.rows[k], col + problem.sizes[k]
    selections.append((torch.arange(j.shape[0]), torch.arange(j.shape[1])))
    for name, (rows, cols) in zip([*names, "both"], selections, strict=True):
        cov_free = normal_inverse(j[rows][:, cols])[:p, :p]
        cov = torch.diag(problem.tolerance.pow(2).nan_to_num(posinf=0.0))
        cov[problem.index[:, None], problem.index[None, :]] = cov_free
        std = torch.full((len(NAMES),), float("nan"), dtype=F64)
        std[problem.index] = cov_free.diagonal().clamp_min(0).sqrt()
        sets.append(name)
        covs.append(cov)
        stds.append(to_display(std))
    return Contributions(tuple(sets), torch.stack(stds), torch.stack(covs))


class JointReport(NamedTuple):
    """What a joint calibration adds to its :class:`~prismstereo.calibration.fit.CalibrationResult`.

    Attributes:
        contributions: the rig's uncertainty from the boards, the scenes and both (:func:`contributions`).
        predicted: the depth uncertainty each set predicts for itself (its covariance propagated to depth at the
            boards' depths), one :class:`~prismstereo.calibration.uncertainty.DepthUncertainty` per set.
        scenes: indices of the scene captures used (among the inputs).
        scene_rms_px: (S,) RMS distance of each used scene's matches from their exact epipolar curves (px).
        scene_sigma_px: the matches' noise estimated from their residuals (px per coordinate).
        matches: the matches used.
        outlier_scenes: indices of scenes left out: their matches disagree with the boards and the other scenes (a
            moving object, a wrong capture).
    """

    contributions: Contributions
    predicted: tuple[DepthUncertainty, ...]
    scenes: tuple[int, ...]
    scene_rms_px: torch.Tensor
    scene_sigma_px: float
    matches: int
    outlier_scenes: tuple[int, ...]


def _problem(rig: BiPrismRig, nominal: BiPrismRig, obs, corr: Correspondences, names: list[str],
             tol: torch.Tensor) -> JointProblem:
    """The joint problem started at ``rig``, its priors on ``nominal``."""
    parts = [BoardProblem(rig, obs, names, tol, sigma_px=0.1), SelfProblem(rig, corr, names, tol, sigma_px=0.3)]
    problem = JointProblem(parts)
    base = rig_vector(nominal)
    for part in (*parts, problem):
        part.base = base
    return problem


def _scene_rms(residuals: torch.Tensor, corr: Correspondences) -> tuple[tuple[int, ...], torch.Tensor]:
    """The scenes with matches and the RMS of each one's residuals (px)."""
    scenes = tuple(sorted(set(corr.view.tolist())))
    rms = torch.stack([residuals[corr.view == v].pow(2).sum(dim=1).nanmean().sqrt() for v in scenes])
    return scenes, rms


def calibrate_joint(
    rig: BiPrismRig,
    boards: Sequence[torch.Tensor | np.ndarray | ViewDetection],
    board: Board,
    scenes: Sequence[torch.Tensor | np.ndarray | Correspondences],
    *,
    fix: Sequence[str] = (),
    free: Sequence[str] = (),
    tolerances: dict[str, float] | None = None,
    min_views: int = 3,
    min_correspondences: int = 50,
    max_correspondences: int = 800,
    outlier_sigma: float = 4.0,
    max_iterations: int = 100,
    max_rms_px: float = 2.0,
    corners: CornerMethod = "symmetric",
    gate_px: float = 25.0,
    progress: bool = False,
) -> CalibrationResult:
    """Calibrate ``rig`` from board captures and ordinary scene captures together (one bundle adjustment).

    The board fixes the metric scale, the scenes' matches the epipolar geometry where a small board leaves it
    weak (principal point, distortion, prism offset). Each input is weighted by the noise its own residuals show.
    After a first fit, matches off their curves by more than ``outlier_sigma`` and scenes whose matches disagree
    as a whole (RMS over 3x the median scene's: a moving object, another rig's capture) are left out, and the fit
    is repeated from the first one (the priors stay on the nominal rig), board views whose error was an outlier
    weighted down to the median view's.

    Args:
        rig: the nominal rig.
        boards: board captures (images or :class:`~prismstereo.calibration.targets.ViewDetection`).
        board: the target.
        scenes: textured scene captures (images or :class:`~prismstereo.calibration.selfcal.Correspondences`).
        fix, free, tolerances, min_views, max_iterations, max_rms_px, corners: as
            :func:`~prismstereo.calibration.fit.calibrate_board`.
        min_correspondences, max_correspondences, gate_px: as
            :func:`~prismstereo.calibration.selfcal.calibrate_self`.
        outlier_sigma: matches with a residual over this many sigma are left out after the first fit.
        progress: progress bars (where stderr is a terminal).

    Returns:
        CalibrationResult of the boards (views, residuals, poses), with ``joint``: the scenes' fit and what each
        input contributed (:class:`JointReport`).

    Raises:
        CalibrationError: the board in too few views, scenes without texture both halves see, a diverged fit.

    Example:
        >>> from prismstereo.calibration import parse_target
        >>> calibrate_joint(thesis_setup1(), [], parse_target("checkerboard:7x5:5"), [])
        Traceback (most recent call last):
        ...
        prismstereo.errors.CalibrationError: no scene captures: pass the boards alone to calibrate_board
    """
    for what, items in (("boards", boards), ("scenes", scenes)):
        if isinstance(items, (torch.Tensor, np.ndarray)):
            raise CalibrationError(f"{what} must be a list of captures (one image per capture), got one array")
    if not scenes:
        raise CalibrationError("no scene captures: pass the boards alone to calibrate_board")
    fixed = set(check_names(fix)) | (set(DEFAULT_FIXED) - set(check_names(free)))
    obs = board_observations(rig, boards, board, min_views=min_views, corners=corners, progress=progress)
    corr = _matches(rig, scenes, gate_px, min_correspondences, max_correspondences, progress)
    names, tol = [n for n in NAMES if n not in fixed], tolerance_vector(rig, tolerances)
    problem = _problem(rig, rig, obs, corr, names, tol)
    solved = solve_rig_problem(problem, max_iterations=max_iterations, max_rms_px=max_rms_px, progress=progress)
    m = obs.uv.shape[0]
    keep, outliers = _scene_outliers(solved.residuals[m:], corr, outlier_sigma * problem.parts[1].sigma_px,
                                     min_correspondences)
    weight, views = view_weights(solved.residuals[:m], obs)
    if not bool(keep.all()) or views:
        corr = Correspondences(corr.left[keep], corr.right[keep], corr.view[keep])
        problem = _problem(solved.rig, rig, obs, corr, names, tol)
        problem.parts[0].weight = weight
        solved = solve_rig_problem(problem, max_iterations=max_iterations, max_rms_px=max_rms_px, progress=progress)
    return _result(rig, problem, solved, obs, corr, outliers, views)


def _scene_outliers(residuals: torch.Tensor, corr: Correspondences, limit_px: float,
                    min_correspondences: int) -> tuple[torch.Tensor, tuple[int, ...]]:
    """The matches to keep for the refit (residual within ``limit_px``, not in an outlier scene) and the outlier
    scenes (input indices): a scene's matches off as a whole (its RMS over 3x the median scene's) are not noise.
    All are kept when fewer than ``min_correspondences`` would remain."""
    keep = residuals.norm(dim=-1) <= limit_px
    used, rms = _scene_rms(residuals, corr)
    outliers = tuple(used[k] for k in range(len(used)) if len(used) > 2 and rms[k] > 3 * rms.median())
    keep &= ~torch.isin(corr.view, torch.tensor(outliers, dtype=corr.view.dtype))
    if int(keep.sum()) < min_correspondences:
        return torch.ones_like(keep), ()
    return keep, outliers


def _result(rig: BiPrismRig, problem: JointProblem, solved, obs, corr: Correspondences, outliers: tuple[int, ...],
            views: tuple[int, ...]) -> CalibrationResult:
    """The joint fit as a :class:`CalibrationResult` of its boards, with its :class:`JointReport`."""
    boards, selfs = problem.parts
    m = obs.uv.shape[0]
    res = solved.residuals[:m]
    board_x = problem.part_x(solved.x, 0)
    depths = _board_depths(boards, board_x)
    found = contributions(problem, solved.x, ["boards", "scenes"])
    predicted = tuple(view_depth_uncertainty(solved.rig, cov, depths) for cov in found.covariance)
    used, rms = _scene_rms(solved.residuals[m:], corr)
    report = JointReport(found, predicted, used, rms, selfs.sigma_px, corr.left.shape[0], outliers)
    view_rms = _per_view_rms(res, obs)
    return CalibrationResult(
        rig=solved.rig, nominal=rig, free=problem.free, data_share=solved.data_share, weak=solved.weak,
        unobservable=(), sigma_px=boards.sigma_px, before=to_display(rig_vector(rig)), after=solved.after,
        std_error=solved.std_error, covariance=solved.covariance, rms_px=float(res.pow(2).sum(dim=1).nanmean().sqrt()),
        depth_uncertainty=predicted[-1], view_rms_px=view_rms, views=obs.views,
        outlier_views=view_outliers(view_rms, obs.views), residuals=res, observations=obs,
        poses=boards.blocks(board_x), iterations=solved.iterations, message=solved.message, joint=report,
        downweighted_views=views,
    )
