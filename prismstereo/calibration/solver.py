"""Levenberg-Marquardt least squares on torch Jacobians, with the statistics a calibration reports.

The calibrations of this package minimise a sum of squared residuals r(x) over a parameter vector x of a few
dozen to a few hundred entries (rig parameters plus board poses). Their Jacobians come from forward-mode
autograd through the exact optics (no hand-derived derivatives), so the solver only needs ``residuals(x)``
and ``jacobian(x)`` callables. Damping follows Marquardt (A + lambda diag(A)), which makes the steps invariant
to the parameters' units; a step is kept only if it lowers the cost, lambda then divided by 10 (Numerical Recipes'
rule: the calibrations' long nonlinear phases take a quarter fewer Jacobians than with a division by 3), else
multiplied by 4.

Statistics (as OpenCV's ``calibrateCameraExtended``): sigma^2 = |r|^2 / (m - n), covariance
sigma^2 (J^T J)^-1, standard errors its diagonal's square roots. Parameters that the data do not determine
show up as near-linear dependencies between the Jacobian's columns: :func:`unobservable` finds them by the
variance inflation of each column (the diagonal of the inverse of the column-normalised J^T J).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import NamedTuple

import torch
from tqdm.auto import tqdm

__all__ = ["LMResult", "levenberg_marquardt", "normal_inverse", "covariance", "unobservable"]


class LMResult(NamedTuple):
    """Result of :func:`levenberg_marquardt`.

    Attributes:
        x: (n,) the solution.
        cost: sum of squared residuals at ``x``.
        initial_cost: at the start.
        iterations: Jacobian evaluations.
        converged: True if the relative cost decrease or the step fell below the tolerances.
        message: why it stopped.
    """

    x: torch.Tensor
    cost: float
    initial_cost: float
    iterations: int
    converged: bool
    message: str


def levenberg_marquardt(
    residuals: Callable[[torch.Tensor], torch.Tensor],
    jacobian: Callable[[torch.Tensor], torch.Tensor],
    x0: torch.Tensor,
    *,
    max_iterations: int = 100,
    cost_tolerance: float = 1e-12,
    step_tolerance: float = 1e-10,
    initial_damping: float = 1e-3,
    progress: bool = False,
    description: str = "fit",
) -> LMResult:
    """Minimise |residuals(x)|^2 from ``x0``.

    Args:
        residuals: x (n,) -> (m,) residuals.
        jacobian: x (n,) -> (m, n) their Jacobian.
        x0: (n,) float64 start.
        max_iterations: Jacobian evaluations at most.
        cost_tolerance: stop when a kept step lowers the cost by less than this fraction.
        step_tolerance: stop when |dx_i| <= tol (|x_i| + tol) for every i.
        initial_damping: Marquardt's lambda at the start.
        progress: show a tqdm bar of the iterations (with the RMS residual) where stderr is a terminal.
        description: the bar's label.

    Returns:
        LMResult.

    Example:
        >>> t = torch.linspace(0, 1, 20, dtype=torch.float64); y = 2.0 * torch.exp(-3.0 * t)
        >>> e = lambda x: torch.exp(-x[1] * t)
        >>> res = levenberg_marquardt(lambda x: x[0] * e(x) - y, lambda x: torch.stack([e(x), -x[0] * t * e(x)], 1),
        ...                           torch.tensor([1.0, 1.0], dtype=torch.float64))
        >>> res.x.round(decimals=6).tolist(), res.converged
        ([2.0, 3.0], True)
    """
    x = x0.clone()
    r = residuals(x)
    cost = float(r @ r)
    initial = cost
    if not math.isfinite(cost):
        return LMResult(x, cost, initial, 0, False, "the cost is not finite at the start (NaN or inf residuals)")
    lam = initial_damping
    message, converged = f"reached max_iterations = {max_iterations}", False
    bar = tqdm(total=max_iterations, desc=description, disable=None if progress else True, leave=False)
    it = 0
    try:
        for it in range(1, max_iterations + 1):
            j = jacobian(x)
            a = j.T @ j
            g = j.T @ r
            diag = a.diagonal().clamp_min(1e-12 * float(a.diagonal().max().clamp_min(1e-300)))
            while True:
                try:
                    dx = torch.linalg.solve(a + lam * torch.diag(diag), -g)
                except RuntimeError:  # singular even with damping: damp more
                    dx = None
                if dx is not None and bool(torch.isfinite(dx).all()):
                    r_new = residuals(x + dx)
                    new_cost = float(r_new @ r_new)
                    if new_cost < cost:
                        break
                lam *= 4.0
                if lam > 1e16:
                    message, converged = "no step lowers the cost (a minimum to working precision)", True
                    return LMResult(x, cost, initial, it, converged, message)
            small_step = bool((dx.abs() <= step_tolerance * (x.abs() + step_tolerance)).all())
            decrease = (cost - new_cost) / max(cost, 1e-300)
            x, r, cost = x + dx, r_new, new_cost
            lam = max(lam / 10.0, 1e-12)
            bar.update(1)
            bar.set_postfix(rms=f"{(cost / max(1, r.numel())) ** 0.5:.4g}")
            if decrease < cost_tolerance or small_step:
                message = "cost decrease below tolerance" if decrease < cost_tolerance else "step below tolerance"
                converged = True
                break
    finally:
        bar.close()
    return LMResult(x, cost, initial, it, converged, message)


def normal_inverse(jacobian: torch.Tensor) -> torch.Tensor:
    """(J^T J)^+ computed on the column-normalised Jacobian: D (J_n^T J_n)^+ D with J_n = J D, D = diag(1 / |J_i|).

    The columns of a calibration's Jacobian mix units (mm, px, rad, dimensionless distortion, board poses), so
    J^T J's condition number reaches 1e13 and a plain pseudo-inverse silently truncates weakly determined
    directions (a principal point traded against tangential distortion) to zero variance: a standard error far
    too small. Normalising the columns first brings the condition number to the geometry's own (~1e8).

    Args:
        jacobian: (m, n).

    Returns:
        (n, n).

    Example:
        >>> j = torch.tensor([[1e6, 0.0], [0.0, 1e-6], [1e6, 1e-6]], dtype=torch.float64)
        >>> normal_inverse(j).diagonal()
        tensor([6.6667e-13, 6.6667e+11], dtype=torch.float64)
    """
    scale = jacobian.norm(dim=0).clamp_min(torch.finfo(jacobian.dtype).tiny)
    normalised = jacobian / scale
    return torch.linalg.pinv(normalised.T @ normalised, hermitian=True) / scale[:, None] / scale[None, :]


def covariance(jacobian: torch.Tensor, cost: float) -> torch.Tensor:
    """Parameter covariance sigma^2 (J^T J)^+ with sigma^2 = cost / (m - n) (:func:`normal_inverse`: a
    pseudo-inverse, so exactly unobservable directions get no variance instead of an error; :func:`unobservable`
    reports them).

    Args:
        jacobian: (m, n) at the solution.
        cost: sum of squared residuals there.

    Returns:
        (n, n) covariance.

    Example:
        >>> covariance(torch.eye(3, dtype=torch.float64).repeat(2, 1), 4.0).diagonal()
        tensor([0.6667, 0.6667, 0.6667], dtype=torch.float64)
    """
    m, n = jacobian.shape
    sigma2 = cost / max(1, m - n)
    return sigma2 * normal_inverse(jacobian)


def unobservable(jacobian: torch.Tensor, candidates: Sequence[int], threshold: float = 1e8) -> list[int]:
    """Columns among ``candidates`` that the others (all columns) nearly reproduce: removed greedily by largest
    variance inflation until every remaining candidate's is below ``threshold``.

    The variance inflation of column i is [(J_n^T J_n)^-1]_ii for the column-normalised J_n: 1 for a column
    orthogonal to the rest, 1 / (1 - R_i^2) in general, infinite for an exact dependency (a pure scale, or a
    parameter with no effect on the residuals).

    Args:
        jacobian: (m, n).
        candidates: column indices that may be removed (e.g. the rig's; poses are never removed).
        threshold: the largest accepted variance inflation.

    Returns:
        The removed column indices, worst first.

    Example:
        >>> j = torch.tensor([[1.0, 2.0, 0.0], [1.0, 2.0, 1.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
        >>> removed = unobservable(j, [0, 1, 2])  # column 1 = 2 x column 0: one of the two goes (a tie: either)
        >>> len(removed), removed[0] in (0, 1)
        (1, True)
    """
    keep = list(range(jacobian.shape[1]))
    removed: list[int] = []
    norms = jacobian.norm(dim=0)
    while True:
        cols = [k for k in keep if norms[k] > 0]
        dead = [k for k in keep if norms[k] == 0 and k in candidates]
        if dead:
            removed.append(dead[0])
            keep.remove(dead[0])
            continue
        jn = jacobian[:, cols] / norms[cols]
        a = jn.T @ jn
        evals, evecs = torch.linalg.eigh(a)
        inv_diag = (evecs.pow(2) / evals.clamp_min(1e-300)).sum(dim=1)
        inflation = {k: float(inv_diag[i]) for i, k in enumerate(cols) if k in candidates}
        if not inflation:
            return removed
        worst = max(inflation, key=inflation.get)
        if inflation[worst] <= threshold:
            return removed
        removed.append(worst)
        keep.remove(worst)
