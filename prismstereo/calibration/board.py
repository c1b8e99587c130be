"""Target-based calibration: board corners seen through both halves, bundle-adjusted through the exact optics.

Unknowns: the free rig parameters (:mod:`prismstereo.calibration.parameters`) and one pose per view (board
-> camera, axis-angle and translation: X = R(w) P + t). Residuals: for every detected corner of every half,
the exact projection of its board point through that half of the prism (:func:`~prismstereo.geometry.optics.
solve_projection`, lens distortion included) minus the detected pixel. Solved by Levenberg-Marquardt
(:mod:`prismstereo.calibration.solver`) from the nominal rig, with Jacobians by forward-mode autograd. The
poses' columns are block-sparse (a view's pose moves only its own corners), so one forward-mode pass with a
shared pose increment gives all of them at once: a Jacobian costs (rig parameters + 6) projections of every
corner, whatever the number of views.

Initial poses: each corner seen in both halves is triangulated with the nominal rig (the two traced rays'
midpoint, the thesis' mid-point theorem) and the board is fitted to those points by Kabsch/Umeyama.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import kornia
import torch
from torch.func import jacfwd

from prismstereo.calibration.parameters import NAMES, check_names, rig_parameters, rig_vector
from prismstereo.calibration.targets import Board, ViewDetection
from prismstereo.errors import CalibrationError
from prismstereo.geometry.optics import solve_projection, trace_pixels
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.geometry.virtual_camera import ray_midpoint

__all__ = ["Observations", "gather_observations", "initial_poses", "BoardProblem"]

F64 = torch.float64


class Observations(NamedTuple):
    """Every detected corner of a calibration, flattened.

    Attributes:
        view: (M,) int64 index of the view (into the kept views).
        left: (M,) bool, True for corners of the left (reference) half.
        points: (M, 3) float64 board points (board frame, mm).
        uv: (M, 2) float64 detected pixels (full sensor).
        views: indices of the kept views among the inputs.
    """

    view: torch.Tensor
    left: torch.Tensor
    points: torch.Tensor
    uv: torch.Tensor
    views: tuple[int, ...]


def gather_observations(detections: Sequence[ViewDetection], board: Board, min_common: int = 4) -> Observations:
    """Keep the views whose board was found in both halves with >= ``min_common`` shared corners, flattened.

    Example:
        >>> from prismstereo.calibration import parse_target
        >>> obs = gather_observations([], parse_target("checkerboard:4x7:6"))
        >>> obs.uv.shape, obs.views
        (torch.Size([0, 2]), ())
    """
    pts = board.points()
    view, left, points, uv, kept = [], [], [], [], []
    for i, det in enumerate(detections):
        if det.left is None or det.right is None:
            continue
        common = set(det.left.ids.tolist()) & set(det.right.ids.tolist())
        if len(common) < min_common:
            continue
        k = len(kept)
        kept.append(i)
        for half, is_left in ((det.left, True), (det.right, False)):
            n = half.ids.numel()
            view.append(torch.full((n,), k, dtype=torch.int64))
            left.append(torch.full((n,), is_left))
            points.append(pts[half.ids])
            uv.append(half.uv.to(F64))
    if not kept:
        return Observations(torch.zeros(0, dtype=torch.int64), torch.zeros(0, dtype=torch.bool),
                            torch.zeros(0, 3, dtype=F64), torch.zeros(0, 2, dtype=F64), ())
    return Observations(torch.cat(view), torch.cat(left), torch.cat(points), torch.cat(uv), tuple(kept))


def _kabsch(src: torch.Tensor, dst: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """R, t minimising |R src + t - dst|^2 (proper rotation)."""
    cs, cd = src.mean(0), dst.mean(0)
    h = (src - cs).T @ (dst - cd)
    u, _, vt = torch.linalg.svd(h)
    d = torch.sign(torch.det(vt.T @ u.T))
    s = torch.diag(torch.tensor([1.0, 1.0, float(d)], dtype=F64))
    r = vt.T @ s @ u.T
    return r, cd - r @ cs


def initial_poses(rig: BiPrismRig, obs: Observations) -> torch.Tensor:
    """(V, 6) board poses (axis-angle, translation) from corners triangulated with ``rig``.

    Raises:
        CalibrationError: if a view's triangulated corners are degenerate (all on a line) or behind the prism.

    Example:
        >>> from prismstereo.calibration import parse_target
        >>> initial_poses(thesis_setup1(), gather_observations([], parse_target("checkerboard:4x7:6"))).shape
        torch.Size([0, 6])
    """
    poses = []
    for k in range(len(obs.views)):
        sel = obs.view == k
        lp, rp = sel & obs.left, sel & ~obs.left
        # pair corners by board point
        lrows, rrows = torch.nonzero(lp).squeeze(1).tolist(), torch.nonzero(rp).squeeze(1).tolist()
        lkey = {tuple(obs.points[i].tolist()): i for i in lrows}
        pairs = [(lkey[tuple(obs.points[j].tolist())], j) for j in rrows if tuple(obs.points[j].tolist()) in lkey]
        li = torch.tensor([a for a, _ in pairs])
        ri = torch.tensor([b for _, b in pairs])
        lr, rr = trace_pixels(rig, obs.uv[li], "left"), trace_pixels(rig, obs.uv[ri], "right")
        x = ray_midpoint(lr.origins, lr.directions, rr.origins, rr.directions)
        board_pts = obs.points[li]
        ok = torch.isfinite(x).all(dim=1) & (x[:, 2] > rig.apex_distance_mm + rig.prism_thickness_mm)
        if int(ok.sum()) < 3 or torch.linalg.matrix_rank(board_pts[ok] - board_pts[ok].mean(0)) < 2:
            raise CalibrationError(f"view {obs.views[k]}: its corners do not triangulate to a board in front of the "
                                   "prism with the nominal rig (is the rig file the right one?)")
        r, t = _kabsch(board_pts[ok], x[ok])
        w = kornia.geometry.conversions.rotation_matrix_to_axis_angle(r[None])[0]
        poses.append(torch.cat([w, t]))
    return torch.stack(poses) if poses else torch.zeros(0, 6, dtype=F64)


class BoardProblem:
    """The least-squares problem of a target calibration: residuals and Jacobian of x = [free rig values, poses].

    Residuals are dimensionless: pixel residuals divided by the corner noise ``sigma_px``, then one prior row
    per free rig parameter, (value - nominal) / tolerance. The priors are the bench tolerances of the nominal rig
    (:data:`~prismstereo.calibration.parameters.TOLERANCES`): a narrow-angle camera's focal length, principal
    point and distortion trade against the board poses, and the prism's alpha against n, so that some
    combinations are barely determined by any set of board views; the prior keeps them at their nominal values
    instead of letting them drift along the valley, and the report says how much of each estimate came from the
    views.

    Args:
        rig: the nominal rig (start values of the rig parameters, pixel size, sensor).
        obs: the observations.
        free: names of the rig parameters to estimate (:data:`~prismstereo.calibration.parameters.NAMES`).
        tolerance: (16,) 1-sigma prior of each parameter in internal units (inf for none).
        sigma_px: the corner detections' noise (px).

    Example:
        >>> from prismstereo.calibration import parse_target
        >>> problem = BoardProblem(thesis_setup1(), gather_observations([], parse_target("checkerboard:4x7:6")),
        ...                        ["k1", "roll_deg"])
        >>> problem.x0.shape
        torch.Size([2])
    """

    def __init__(self, rig: BiPrismRig, obs: Observations, free: Sequence[str],
                 tolerance: torch.Tensor | None = None, sigma_px: float = 0.1) -> None:
        self.rig, self.obs, self.sigma_px = rig, obs, float(sigma_px)
        self.free = check_names(free)
        self.index = torch.tensor([NAMES.index(n) for n in self.free], dtype=torch.int64)
        self.base = rig_vector(rig)
        self.distorted = rig.distorted or any(n in self.free for n in ("k1", "k2", "p1", "p2", "k3"))
        self.num_views = len(obs.views)
        self._warm: torch.Tensor | None = None
        self._left_rows = torch.nonzero(obs.left).squeeze(1)
        self._right_rows = torch.nonzero(~obs.left).squeeze(1)
        self._order = torch.argsort(torch.cat([self._left_rows, self._right_rows]))
        poses = initial_poses(rig, obs) if self.num_views else torch.zeros(0, 6, dtype=F64)
        self.x0 = torch.cat([self.base[self.index], poses.reshape(-1)])
        tol = torch.full((len(NAMES),), float("inf"), dtype=F64) if tolerance is None else tolerance.to(F64)
        self.prior_weight = 1.0 / tol[self.index]  # 0 where there is no prior

    @property
    def num_rig(self) -> int:
        """Number of free rig parameters (the first entries of x)."""
        return len(self.free)

    def full_vector(self, x: torch.Tensor) -> torch.Tensor:
        """(16,) rig vector with the free entries taken from x."""
        return self.base.to(x).index_put((self.index,), x[: self.num_rig])

    def _project(self, x_rig: torch.Tensor, poses: torch.Tensor, warm: torch.Tensor | None,
                 iterations: int) -> tuple[torch.Tensor, torch.Tensor]:
        p = rig_parameters(self.full_vector(x_rig), self.rig, self.distorted)
        obs = self.obs
        rot = kornia.geometry.conversions.axis_angle_to_rotation_matrix(poses[:, :3])  # (V, 3, 3)
        pts = (rot[obs.view] @ obs.points.to(poses).unsqueeze(-1)).squeeze(-1) + poses[obs.view, 3:]
        uvs, valids = [], []
        for half, rows in (("left", self._left_rows), ("right", self._right_rows)):
            proj = solve_projection(p, pts[rows], half, iterations, None if warm is None else warm[rows])
            uvs.append(proj.uv)
            valids.append(proj.valid)
        return torch.cat(uvs)[self._order], torch.cat(valids)[self._order]

    def _split(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return x[: self.num_rig], x[self.num_rig:].view(-1, 6)

    def projections(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(M, 2) exact projections of every observed corner at x, and (M,) their validity."""
        with torch.no_grad():
            x_rig, poses = self._split(x)
            uv, valid = self._project(x_rig, poses, self._warm, 5)
            self._warm = uv.detach()
        return uv, valid

    def residuals(self, x: torch.Tensor) -> torch.Tensor:
        """(2M + P,) (projection - detection) / sigma_px, u and v interleaved per corner, then the P prior rows."""
        uv, _ = self.projections(x)
        prior = (x[: self.num_rig] - self.base[self.index]) * self.prior_weight
        return torch.cat([(uv - self.obs.uv).reshape(-1) / self.sigma_px, prior])

    def jacobian(self, x: torch.Tensor) -> torch.Tensor:
        """(2M, n) Jacobian of :meth:`residuals` by forward-mode autograd (one pass per rig parameter + 6)."""
        x_rig, poses = self._split(x)
        warm, _ = self.projections(x)  # converged start: one Newton step carries the derivative

        def f(z: torch.Tensor) -> torch.Tensor:
            return self._project(z[: self.num_rig], poses + z[self.num_rig:], warm, 1)[0]

        z = torch.cat([x_rig, torch.zeros(6, dtype=x.dtype)])
        j = jacfwd(f)(z).reshape(-1, self.num_rig + 6)  # (2M, P + 6)
        m = j.shape[0]
        full = torch.zeros(m + self.num_rig, x.numel(), dtype=x.dtype)
        full[:m, : self.num_rig] = j[:, : self.num_rig] / self.sigma_px
        rows = torch.arange(m)
        view = self.obs.view.repeat_interleave(2)
        for c in range(6):
            full[rows, self.num_rig + 6 * view + c] = j[:, self.num_rig + c] / self.sigma_px
        full[m + torch.arange(self.num_rig), torch.arange(self.num_rig)] = self.prior_weight
        return full
