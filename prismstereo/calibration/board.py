"""Target-based calibration: board corners seen through both halves, bundle-adjusted through the exact optics.

Unknowns: the free rig parameters (:mod:`prismstereo.calibration.parameters`) and one pose per view (board
-> camera, axis-angle and translation: X = R(w) P + t). Residuals: for every detected corner of every half,
the exact projection of its board point through that half of the prism (:func:`~prismstereo.geometry.projection.
solve_projection`, lens distortion included) minus the detected pixel, with the priors and Jacobian of
:class:`~prismstereo.calibration.problem.RigProblem`; solved by Levenberg-Marquardt
(:mod:`prismstereo.calibration.solver`) from the nominal rig.

Initial poses: each corner seen in both halves is triangulated with the nominal rig (the two traced rays'
midpoint, the thesis' mid-point theorem) and the board is fitted to those points by Kabsch/Umeyama.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import torch

from prismstereo.calibration.problem import RigProblem
from prismstereo.calibration.targets import Board, ViewDetection
from prismstereo.errors import CalibrationError
from prismstereo.geometry.optics import trace_pixels
from prismstereo.geometry.parameters import RigParameters
from prismstereo.geometry.projection import solve_projection
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.geometry.virtual_camera import ray_midpoint

__all__ = ["Observations", "gather_observations", "initial_poses", "rigid_fit", "BoardProblem"]

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


def rigid_fit(src: torch.Tensor, dst: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The proper rotation R (3, 3) and translation t (3,) minimising |R src + t - dst|^2 (Kabsch / Umeyama
    without scale) for matched points src, dst (N, 3), N >= 3 not on a line.

    Example:
        >>> src = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=torch.float64)
        >>> r, t = rigid_fit(src, src + torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))
        >>> t.round(decimals=6).tolist()
        [1.0, 2.0, 3.0]
    """
    if src.shape != dst.shape or src.dim() != 2 or src.shape[1] != 3 or src.shape[0] < 3:
        raise CalibrationError(f"rigid_fit needs matched (N, 3) point sets with N >= 3, got {tuple(src.shape)} and "
                               f"{tuple(dst.shape)}")
    cs, cd = src.mean(0), dst.mean(0)
    h = (src - cs).T @ (dst - cd)
    u, _, vt = torch.linalg.svd(h)
    d = torch.sign(torch.det(vt.T @ u.T))
    s = torch.diag(torch.stack([torch.ones_like(d), torch.ones_like(d), d]))
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
    # kornia imported where used: a cached graph's depth run never loads it
    from kornia.geometry.conversions import rotation_matrix_to_axis_angle

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
        r, t = rigid_fit(board_pts[ok], x[ok])
        w = rotation_matrix_to_axis_angle(r[None])[0]
        poses.append(torch.cat([w, t]))
    return torch.stack(poses) if poses else torch.zeros(0, 6, dtype=F64)


class BoardProblem(RigProblem):
    """The least-squares problem of a target calibration: x = [free rig values, board poses (V, 6)]; the
    residuals, priors and Jacobian are :class:`~prismstereo.calibration.problem.RigProblem`'s.

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
        self.obs = obs
        self._left_rows = torch.nonzero(obs.left).squeeze(1)
        self._right_rows = torch.nonzero(~obs.left).squeeze(1)
        self._order = torch.argsort(torch.cat([self._left_rows, self._right_rows]))
        poses = initial_poses(rig, obs) if obs.views else torch.zeros(0, 6, dtype=F64)
        super().__init__(rig, free, obs.uv, obs.view, poses, tolerance, sigma_px)

    def predict(self, p: RigParameters, blocks: torch.Tensor, warm: torch.Tensor | None,
                iterations: int) -> tuple[torch.Tensor, torch.Tensor]:
        """The exact projection of every corner's board point, posed by its view's (axis-angle, translation)."""
        obs = self.obs
        # kornia imported where used: a cached graph's depth run never loads it
        from kornia.geometry.conversions import axis_angle_to_rotation_matrix

        rot = axis_angle_to_rotation_matrix(blocks[:, :3])  # (V, 3, 3)
        pts = (rot[obs.view] @ obs.points.to(blocks).unsqueeze(-1)).squeeze(-1) + blocks[obs.view, 3:]
        uvs, valids = [], []
        for half, rows in (("left", self._left_rows), ("right", self._right_rows)):
            proj = solve_projection(p, pts[rows], half, iterations, None if warm is None else warm[rows])
            uvs.append(proj.uv)
            valids.append(proj.valid)
        return torch.cat(uvs)[self._order], torch.cat(valids)[self._order]
