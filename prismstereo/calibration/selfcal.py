"""Self-calibration from ordinary captures: no target, correspondences between the halves and the exact epipolar
curves.

A correspondence pairs a left (reference) pixel with the right-half pixel of the same scene point. For a rig,
the left pixel's traced ray and a depth Z along it give a point, whose exact projection through the right half
must be the right pixel: the unknowns are the free rig parameters and one depth per correspondence, the
residuals that projection minus the right pixel (:class:`SelfProblem`, the shared machinery of
:class:`~prismstereo.calibration.problem.RigProblem`). Minimising them over the depths alone puts each right
pixel on its left pixel's exact epipolar curve (thesis ch. 4, in its exact form), so the fit moves the rig until
every curve passes through its match.

Not everything is observable this way. Scaling the scene and every length of the prism (T_o, T, d) together
leaves every image unchanged: with no target there is no metric scale but the one the prism's drawing gives, so
T stays fixed (:data:`~prismstereo.calibration.fit.DEFAULT_FIXED`), and parameters whose Jacobian columns the
others reproduce (variance inflation above a threshold, :func:`~prismstereo.calibration.solver.unobservable`) are
held at their nominal values and reported instead of being fitted to noise. What the views barely determine
stays near nominal by its tolerance and is listed as weak.

Correspondences: SIFT features in each half (OpenCV), mutual nearest neighbours with Lowe's ratio test, gated by
the nominal rig (the two traced rays must pass within ``gate_px`` pixels of each other at the point's depth).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import cv2
import numpy as np
import torch
from tqdm.auto import tqdm

from prismstereo.calibration.board import Observations
from prismstereo.calibration.fit import (
    DEFAULT_FIXED,
    CalibrationResult,
    SolvedProblem,
    solve_rig_problem,
    view_depth_uncertainty,
    view_outliers,
)
from prismstereo.calibration.parameters import NAMES, check_names, rig_vector, to_display, tolerance_vector
from prismstereo.calibration.problem import RigProblem
from prismstereo.calibration.solver import unobservable
from prismstereo.calibration.targets import to_gray_u8
from prismstereo.errors import CalibrationError
from prismstereo.geometry.optics import points_at_depth, trace_pixels
from prismstereo.geometry.parameters import RigParameters
from prismstereo.geometry.projection import solve_projection
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.geometry.virtual_camera import ray_midpoint

__all__ = ["Correspondences", "find_correspondences", "gate", "SelfProblem", "calibrate_self"]

F64 = torch.float64


class Correspondences(NamedTuple):
    """Matched pixels of the two halves.

    Attributes:
        left: (N, 2) float64 reference-half pixels (full sensor).
        right: (N, 2) float64 right-half pixels (full sensor).
        view: (N,) int64 capture index.
    """

    left: torch.Tensor
    right: torch.Tensor
    view: torch.Tensor


def _triangulate(rig: BiPrismRig | RigParameters, left: torch.Tensor, right: torch.Tensor) -> tuple[torch.Tensor,
                                                                                                   torch.Tensor]:
    """Midpoints (N, 3) of the two traced rays and their gap (N,) in pixels at the midpoint's depth."""
    lr, rr = trace_pixels(rig, left, "left"), trace_pixels(rig, right, "right")
    x = ray_midpoint(lr.origins, lr.directions, rr.origins, rr.directions)
    on_left = points_at_depth(lr, x[:, 2])
    fpx = (rig.focal_length_px if isinstance(rig, BiPrismRig) else float(rig.f / rig.pixel_size))
    gap = 2.0 * (x - on_left).norm(dim=-1) / x[:, 2].abs().clamp_min(1e-9) * fpx
    return x, torch.where(lr.valid & rr.valid, gap, torch.full_like(gap, float("inf")))


def find_correspondences(
    image: torch.Tensor | np.ndarray,
    rig: BiPrismRig,
    *,
    max_features: int = 4000,
    ratio: float = 0.8,
    gate_px: float = 25.0,
    view: int = 0,
) -> Correspondences:
    """SIFT correspondences between the two halves of one capture, gated by the nominal rig.

    Args:
        image: one capture ((C, H, W) / (H, W) float tensor in [0, 1] or uint8 array).
        rig: the nominal rig (split, sensor size, gate).
        max_features: SIFT features per half.
        ratio: Lowe's ratio test threshold.
        gate_px: the nominal rig's two rays must pass within this many pixels of each other (a misaligned rig's
            epipolar curves are off by a few pixels; wrong matches by many).
        view: capture index stored with the matches.

    Returns:
        Correspondences.

    Raises:
        CalibrationError: the image's size is not the rig's.

    Example:
        >>> find_correspondences(torch.zeros(1, 192, 256), thesis_setup1().downscaled(4)).left.shape
        torch.Size([0, 2])
    """
    gray = to_gray_u8(image)
    if gray.shape != (rig.image_height, rig.image_width):
        raise CalibrationError(f"image is {gray.shape[1]}x{gray.shape[0]} px but the rig's sensor is "
                               f"{rig.image_width}x{rig.image_height}")
    split = rig.reference_width
    sift = cv2.SIFT_create(nfeatures=max_features)
    kl, dl = sift.detectAndCompute(np.ascontiguousarray(gray[:, :split]), None)
    kr, dr = sift.detectAndCompute(np.ascontiguousarray(gray[:, split:]), None)
    empty = Correspondences(torch.zeros(0, 2, dtype=F64), torch.zeros(0, 2, dtype=F64),
                            torch.zeros(0, dtype=torch.long))
    if dl is None or dr is None or len(kl) < 2 or len(kr) < 2:
        return empty
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    forward = matcher.knnMatch(dl, dr, k=2)
    backward = {m[0].queryIdx: m[0].trainIdx for m in matcher.knnMatch(dr, dl, k=2) if m}
    pairs = [(m[0].queryIdx, m[0].trainIdx) for m in forward
             if len(m) == 2 and m[0].distance < ratio * m[1].distance and backward.get(m[0].trainIdx) == m[0].queryIdx]
    if not pairs:
        return empty
    left = torch.tensor([kl[i].pt for i, _ in pairs], dtype=F64)
    right = torch.tensor([kr[j].pt for _, j in pairs], dtype=F64) + torch.tensor([float(split), 0.0], dtype=F64)
    return gate(rig, Correspondences(left, right, torch.full((left.shape[0],), view, dtype=torch.long)), gate_px)


def gate(rig: BiPrismRig, corr: Correspondences, gate_px: float = 25.0) -> Correspondences:
    """Keep the matches the nominal rig can explain: both traced rays valid (the left pixel in the left half, the
    right one in the right half), meeting within ``gate_px`` pixels, in front of the prism's back plane.

    Example:
        >>> c = Correspondences(torch.tensor([[100.0, 50.0]], dtype=torch.float64),
        ...                     torch.tensor([[20.0, 50.0]], dtype=torch.float64), torch.zeros(1, dtype=torch.long))
        >>> gate(thesis_setup1().downscaled(4), c).left.shape  # the "right" pixel is in the left half
        torch.Size([0, 2])
    """
    if corr.left.numel() == 0:
        return corr
    x, gap = _triangulate(rig, corr.left.to(F64), corr.right.to(F64))
    keep = (gap < gate_px) & (x[:, 2] > rig.apex_distance_mm + rig.prism_thickness_mm)
    return Correspondences(corr.left[keep].to(F64), corr.right[keep].to(F64), corr.view[keep])


class SelfProblem(RigProblem):
    """Self-calibration as least squares: x = [free rig values, depth Z (mm) of each correspondence].

    Args:
        rig: the nominal rig.
        corr: the correspondences.
        free: rig parameters to estimate.
        tolerance: (16,) 1-sigma priors in internal units.
        sigma_px: the matches' noise (px).

    Example:
        >>> corr = Correspondences(torch.zeros(0, 2, dtype=torch.float64), torch.zeros(0, 2, dtype=torch.float64),
        ...                        torch.zeros(0, dtype=torch.long))
        >>> SelfProblem(thesis_setup1(), corr, ["roll_deg"]).x0.shape
        torch.Size([1])
    """

    def __init__(self, rig: BiPrismRig, corr: Correspondences, free: Sequence[str],
                 tolerance: torch.Tensor | None = None, sigma_px: float = 0.3) -> None:
        self.corr = corr
        depth = _triangulate(rig, corr.left, corr.right)[0][:, 2:] if corr.left.numel() else torch.zeros(0, 1)
        n = corr.left.shape[0]
        super().__init__(rig, free, corr.right, torch.arange(n), depth.to(F64), tolerance, sigma_px)

    def predict(self, p: RigParameters, blocks: torch.Tensor, warm: torch.Tensor | None,
                iterations: int) -> tuple[torch.Tensor, torch.Tensor]:
        """The right-half projection of the point at depth Z on each left pixel's traced ray."""
        rays = trace_pixels(p, self.corr.left.to(blocks), "left")
        points = points_at_depth(rays, blocks[:, 0])
        proj = solve_projection(p, points, "right", iterations, warm)
        return proj.uv, proj.valid & rays.valid


def calibrate_self(
    rig: BiPrismRig,
    captures: Sequence[torch.Tensor | np.ndarray | Correspondences],
    *,
    fix: Sequence[str] = (),
    free: Sequence[str] = (),
    tolerances: dict[str, float] | None = None,
    max_iterations: int = 100,
    max_rms_px: float = 2.0,
    min_correspondences: int = 50,
    max_correspondences: int = 800,
    observability_threshold: float = 1e6,
    outlier_sigma: float = 4.0,
    gate_px: float = 25.0,
    progress: bool = False,
) -> CalibrationResult:
    """Self-calibrate ``rig`` from one to a few ordinary captures of textured scenes (no target).

    Args:
        rig: the nominal rig.
        captures: images or their :class:`Correspondences`.
        fix: rig parameters to hold at nominal besides :data:`~prismstereo.calibration.fit.DEFAULT_FIXED`.
        free: default-fixed parameters to estimate after all.
        tolerances: 1-sigma priors overriding the defaults (reported units).
        max_iterations: solver iterations per pass.
        max_rms_px: a final RMS above this is a diverged fit.
        min_correspondences: matches required after the gates.
        max_correspondences: at most this many matches are used (a seeded random subset, spread over the captures):
            a dozen rig parameters need hundreds of matches, not thousands, and the cost grows with them.
        observability_threshold: variance inflation above which a parameter counts as not observable from the
            matches and is held at nominal (reported as ``unobservable``).
        outlier_sigma: after a first fit, matches whose residual exceeds this many sigma (of one coordinate; the
            residual is essentially across the curve, the depth absorbs the rest) are dropped and the fit repeated.
        gate_px: the nominal rig's gate on the matches (:func:`gate`), applied to given correspondences too.
        progress: progress bars (where stderr is a terminal).

    Returns:
        CalibrationResult: ``views`` are the captures, ``view_rms_px`` the right-half residual per capture (left
        column NaN: the left pixels are the rays' origins), ``poses`` the matches' depths (N, 1) (mm),
        ``unobservable`` the parameters held at nominal because the matches cannot determine them.

    Raises:
        CalibrationError: no captures, too few correspondences, unknown names, or a diverged fit.

    Example:
        >>> calibrate_self(thesis_setup1(), [])
        Traceback (most recent call last):
        ...
        prismstereo.errors.CalibrationError: no captures to self-calibrate from
    """
    if isinstance(captures, (torch.Tensor, np.ndarray)):
        raise CalibrationError("captures must be a list of images (one tensor or array per capture), got one "
                               f"{type(captures).__name__}")
    if not captures:
        raise CalibrationError("no captures to self-calibrate from")
    fixed = set(check_names(fix)) | (set(DEFAULT_FIXED) - set(check_names(free)))
    corr = _matches(rig, captures, gate_px, min_correspondences, max_correspondences, progress)
    names = [n for n in NAMES if n not in fixed]
    tol = tolerance_vector(rig, tolerances)
    names, unobservable_names = _observable(rig, corr, names, tol, observability_threshold)
    corr, problem, solved = _fit(rig, corr, names, tol, min_correspondences=min_correspondences,
                                 outlier_sigma=outlier_sigma, max_iterations=max_iterations, max_rms_px=max_rms_px,
                                 progress=progress)
    return _result(rig, corr, problem, solved, unobservable_names)


def _matches(rig: BiPrismRig, captures: Sequence[torch.Tensor | np.ndarray | Correspondences], gate_px: float,
             min_correspondences: int, max_correspondences: int, progress: bool) -> Correspondences:
    """The captures' gated correspondences: at least ``min_correspondences``, at most ``max_correspondences`` (a
    seeded random subset, kept in capture order)."""
    found = [gate(rig, c, gate_px) if isinstance(c, Correspondences) else find_correspondences(c, rig, view=i,
                                                                                               gate_px=gate_px)
             for i, c in enumerate(tqdm(captures, desc="match", disable=None if progress else True, leave=False))]
    corr = Correspondences(*(torch.cat(t) for t in zip(*found, strict=True)))
    if corr.left.shape[0] < min_correspondences:
        raise CalibrationError(f"{corr.left.shape[0]} correspondences between the halves, need {min_correspondences}: "
                               "the scenes need texture seen by both halves")
    if corr.left.shape[0] > max_correspondences:
        keep = torch.randperm(corr.left.shape[0], generator=torch.Generator().manual_seed(0))[:max_correspondences]
        keep = keep.sort().values
        corr = Correspondences(corr.left[keep], corr.right[keep], corr.view[keep])
    return corr


def _observable(rig: BiPrismRig, corr: Correspondences, names: list[str], tol: torch.Tensor,
                threshold: float) -> tuple[list[str], tuple[str, ...]]:
    """The free parameters the matches determine (variance inflation of their Jacobian columns at the nominal rig
    up to ``threshold``), and the others, which stay at nominal."""
    problem = SelfProblem(rig, corr, names, tol)
    data_rows = 2 * corr.left.shape[0]
    lost = unobservable(problem.jacobian(problem.x0)[:data_rows], range(problem.num_rig), threshold)
    unobservable_names = tuple(names[i] for i in lost)
    return [n for n in names if n not in unobservable_names], unobservable_names


def _fit(rig: BiPrismRig, corr: Correspondences, names: list[str], tol: torch.Tensor, *, min_correspondences: int,
         outlier_sigma: float, max_iterations: int, max_rms_px: float,
         progress: bool) -> tuple[Correspondences, SelfProblem, SolvedProblem]:
    """Fit ``names``; then drop the matches whose residual exceeds ``outlier_sigma`` sigma and fit again from the
    first fit (the priors stay on the nominal rig), unless fewer than ``min_correspondences`` would remain.
    Returns the matches used, the last problem and its solution."""
    problem = SelfProblem(rig, corr, names, tol)
    solved = solve_rig_problem(problem, max_iterations=max_iterations, max_rms_px=max_rms_px, progress=progress)
    off = solved.residuals.norm(dim=-1) > outlier_sigma * problem.sigma_px
    if bool(off.any()) and int((~off).sum()) >= min_correspondences:
        corr = Correspondences(corr.left[~off], corr.right[~off], corr.view[~off])
        problem = SelfProblem(solved.rig, corr, names, tol, problem.sigma_px)
        problem.base = rig_vector(rig)  # the priors stay on the nominal rig
        solved = solve_rig_problem(problem, max_iterations=max_iterations, max_rms_px=max_rms_px, progress=progress)
    return corr, problem, solved


def _result(rig: BiPrismRig, corr: Correspondences, problem: SelfProblem, solved: SolvedProblem,
            unobservable_names: tuple[str, ...]) -> CalibrationResult:
    """The fit as a :class:`CalibrationResult`: per-capture right-half RMS, the matches' depths as poses and their
    points as observations."""
    views = tuple(sorted(set(corr.view.tolist())))
    rms = torch.full((len(views), 2), float("nan"), dtype=F64)
    for k, v in enumerate(views):
        sel = corr.view == v
        rms[k, 1] = solved.residuals[sel].pow(2).sum(dim=1).nanmean().sqrt()
    depths = problem.blocks(solved.x)
    points = points_at_depth(trace_pixels(solved.rig, corr.left, "left"), depths[:, 0])
    obs = Observations(torch.tensor([views.index(v) for v in corr.view.tolist()], dtype=torch.long),
                       torch.zeros(corr.left.shape[0], dtype=torch.bool), points, corr.right, views)
    return CalibrationResult(
        rig=solved.rig, nominal=rig, free=problem.free, data_share=solved.data_share,
        weak=solved.weak, unobservable=unobservable_names, sigma_px=problem.sigma_px,
        before=to_display(rig_vector(rig)),
        after=solved.after, std_error=solved.std_error, covariance=solved.covariance, rms_px=solved.rms_px,
        depth_uncertainty=view_depth_uncertainty(solved.rig, solved.covariance, depths[:, 0]), view_rms_px=rms,
        views=views,
        outlier_views=view_outliers(rms[:, 1:].nan_to_num(0.0), views), residuals=solved.residuals, observations=obs,
        poses=depths, iterations=solved.iterations, message=solved.message,
    )
