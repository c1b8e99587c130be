"""The least-squares structure shared by the calibrations: free rig parameters plus per-block unknowns.

Both calibrations estimate the rig's free parameters together with unknowns that belong to one group of
observations each: a board pose per view (6 values, :mod:`~prismstereo.calibration.board`) or a depth per
correspondence (1 value, :mod:`~prismstereo.calibration.selfcal`). :class:`RigProblem` holds what they share:

- x = [free rig values (internal units), block unknowns (K, b) flattened];
- residuals, dimensionless: (predicted - observed pixel) / sigma_px per observation (u and v interleaved), then
  one prior row per free rig parameter, (value - nominal) / tolerance (the nominal rig's bench tolerances,
  :data:`~prismstereo.calibration.parameters.TOLERANCES`; a tolerance of inf means no prior). Without priors
  some combinations (a narrow-angle camera's focal length against the target's distance, alpha against n) are
  barely determined by any set of views and drift along their valley;
- the Jacobian by forward-mode autograd through the exact optics. The block columns are block-sparse (a block's
  unknowns move only its own observations), so one forward pass with a shared increment of all blocks gives them
  all: a Jacobian costs (free rig parameters + b) passes, whatever the number of blocks. Each pass starts the
  Newton projection from the converged pixels, so one differentiable step carries the exact derivative.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch.func import jacfwd

from prismstereo.calibration.parameters import NAMES, check_names, rig_parameters, rig_vector
from prismstereo.geometry.parameters import RigParameters
from prismstereo.geometry.rig import BiPrismRig

__all__ = ["RigProblem"]

F64 = torch.float64


class RigProblem:
    """Residuals and Jacobian of a calibration; subclasses define :meth:`predict`.

    Args:
        rig: the nominal rig (start of the rig parameters; pixel size and sensor).
        free: names of the rig parameters to estimate (:data:`~prismstereo.calibration.parameters.NAMES`).
        observed: (M, 2) observed pixels.
        block: (M,) int64 block of each observation.
        blocks0: (K, b) start values of the block unknowns.
        tolerance: (16,) 1-sigma priors in internal units (inf: none); default none.
        sigma_px: the observations' noise (px per coordinate).

    Example:
        >>> problem = RigProblem(thesis_setup1(), ["k1"], torch.zeros(0, 2, dtype=torch.float64),
        ...                      torch.zeros(0, dtype=torch.int64), torch.zeros(0, 6, dtype=torch.float64))
        >>> problem.x0.shape, problem.num_rig
        (torch.Size([1]), 1)
    """

    def __init__(self, rig: BiPrismRig, free: Sequence[str], observed: torch.Tensor, block: torch.Tensor,
                 blocks0: torch.Tensor, tolerance: torch.Tensor | None = None, sigma_px: float = 0.1) -> None:
        self.rig, self.sigma_px = rig, float(sigma_px)
        self.free = check_names(free)
        self.index = torch.tensor([NAMES.index(n) for n in self.free], dtype=torch.int64)
        self.base = rig_vector(rig)
        self.distorted = rig.distorted or any(n in self.free for n in ("k1", "k2", "p1", "p2", "k3"))
        self.observed, self.block = observed.to(F64), block
        self.block_size = blocks0.shape[1]
        self.x0 = torch.cat([self.base[self.index], blocks0.to(F64).reshape(-1)])
        tol = torch.full((len(NAMES),), float("inf"), dtype=F64) if tolerance is None else tolerance.to(F64)
        self.tolerance = tol
        self.prior_weight = 1.0 / tol[self.index]  # 0 where there is no prior
        self._warm: torch.Tensor | None = None
        # the last projections and their x: Levenberg-Marquardt asks for the Jacobian at the x whose residuals it
        # has just computed (the accepted step), and the Jacobian starts from those projections
        self._last: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor] | None = None
        # observations that take part; solve_rig_problem drops the ones the start cannot project (a fixed mask:
        # rows that dropped out during the fit would lower the cost without fitting anything)
        self.active = torch.ones(observed.shape[0], dtype=torch.bool)
        # each observation's weight on its residual (1; a robust refit lowers an outlier view's)
        self.weight = torch.ones(observed.shape[0], dtype=F64)

    @property
    def num_rig(self) -> int:
        """Number of free rig parameters (the first entries of x)."""
        return len(self.free)

    def predict(self, p: RigParameters, blocks: torch.Tensor, warm: torch.Tensor | None,
                iterations: int) -> tuple[torch.Tensor, torch.Tensor]:  # pragma: no cover - abstract
        """(M, 2) predicted pixels and (M,) validity for rig ``p`` and block unknowns (K, b); ``warm`` (M, 2) are
        converged pixels to start the Newton projections from (None: the virtual-pinhole start)."""
        raise NotImplementedError

    def full_vector(self, x: torch.Tensor) -> torch.Tensor:
        """(16,) rig vector with the free entries taken from x."""
        return self.base.to(x).index_put((self.index,), x[: self.num_rig])

    def blocks(self, x: torch.Tensor) -> torch.Tensor:
        """(K, b) block unknowns of x."""
        return x[self.num_rig:].view(-1, self.block_size)

    def _predict(self, x_rig: torch.Tensor, blocks: torch.Tensor, warm: torch.Tensor | None,
                 iterations: int) -> tuple[torch.Tensor, torch.Tensor]:
        return self.predict(rig_parameters(self.full_vector(x_rig), self.rig, self.distorted), blocks, warm,
                            iterations)

    def projections(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(M, 2) predicted pixels at x and (M,) their validity (no autograd; those of the last x are kept)."""
        last = self._last
        if last is not None and last[3] is self.base and last[0].shape == x.shape and torch.equal(last[0], x):
            return last[1], last[2]
        with torch.no_grad():
            uv, valid = self._predict(x[: self.num_rig], self.blocks(x), self._warm, 5)
            # unconverged rows restart from the virtual-pinhole guess next time (solve_projection's NaN start)
            self._warm = torch.where(valid.unsqueeze(-1), uv.detach(), torch.full_like(uv, float("nan")))
        self._last = (x.detach().clone(), uv, valid, self.base)  # (a new base, e.g. selfcal's priors: recomputed)
        return uv, valid

    def prior_rows(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The P prior rows at x (the free rig values held to the nominal ones within their tolerances): their
        residuals (P,), (x_rig - nominal) * prior_weight, and their Jacobian (P, n).

        Example:
            >>> residuals, jacobian = problem.prior_rows(problem.x0)  # doctest: +SKIP
        """
        p = self.num_rig
        jacobian = torch.zeros(p, x.numel(), dtype=x.dtype)
        jacobian[torch.arange(p), torch.arange(p)] = self.prior_weight
        return (x[:p] - self.base[self.index]) * self.prior_weight, jacobian

    def residuals(self, x: torch.Tensor) -> torch.Tensor:
        """(2M + P,) (predicted - observed) / sigma_px, u and v interleaved (zero for inactive observations), then
        the P prior rows."""
        uv, _ = self.projections(x)
        res = torch.where(self.active.unsqueeze(-1), (uv - self.observed) * self.weight.unsqueeze(-1),
                          torch.zeros_like(uv))
        return torch.cat([res.reshape(-1) / self.sigma_px, self.prior_rows(x)[0]])

    def reweight(self, x: torch.Tensor, *, rig_unknowns: float | None = None) -> bool:
        """Set ``sigma_px`` to the noise the weighted residuals at x show (their RMS per coordinate over the degrees
        of freedom: the observations' coordinates less the unknowns, of which ``rig_unknowns`` rig ones when this
        problem shares them with others, :class:`~prismstereo.calibration.joint.JointProblem`); whether it had
        settled (the new value within 20 % of the old one).

        Example:
            >>> problem.reweight(solution)  # doctest: +SKIP
            True
        """
        res = (self.projections(x)[0] - self.observed) * self.weight.unsqueeze(-1)
        res = torch.where(self.active.unsqueeze(-1), res, torch.full_like(res, float("nan")))
        unknowns = x.numel() if rig_unknowns is None else x.numel() - self.num_rig + rig_unknowns
        dof = max(1.0, int(self.active.sum()) * 2 - unknowns)
        sigma = max(float(res.pow(2).nansum() / dof) ** 0.5, 1e-3)
        settled = 0.8 < sigma / self.sigma_px < 1.25
        self.sigma_px = sigma
        return settled

    def jacobian(self, x: torch.Tensor) -> torch.Tensor:
        """(2M + P, n) Jacobian of :meth:`residuals` by forward-mode autograd."""
        p, b = self.num_rig, self.block_size
        blocks = self.blocks(x)
        warm, _ = self.projections(x)

        def f(z: torch.Tensor) -> torch.Tensor:
            return self._predict(z[:p], blocks + z[p:], warm, 0)[0]  # warm: converged at x

        z = torch.cat([x[:p], torch.zeros(b, dtype=x.dtype)])
        j = jacfwd(f)(z).reshape(-1, p + b)  # (2M, P + b)
        m = j.shape[0]
        full = torch.zeros(m + p, x.numel(), dtype=x.dtype)
        full[:m, :p] = j[:, :p] / self.sigma_px
        rows = torch.arange(m)
        block = self.block.repeat_interleave(2)
        for c in range(b):
            full[rows, p + b * block + c] = j[:, p + c] / self.sigma_px
        full[:m] *= (self.active.to(full) * self.weight.to(full)).repeat_interleave(2).unsqueeze(-1)
        full[m:] = self.prior_rows(x)[1]
        return full
