"""The least-squares structure the calibrations share (:class:`prismstereo.calibration.problem.RigProblem`): the
residuals' layout (observations u, v interleaved over sigma, then one prior row per free parameter) and the
block-sparse Jacobian against finite differences, on a problem whose prediction is known in closed form."""

import torch

from prismstereo import thesis_setup1
from prismstereo.calibration.parameters import NAMES
from prismstereo.calibration.problem import RigProblem

F64 = torch.float64


class Shifted(RigProblem):
    """Each observation is its block's 2-vector plus k1 on both coordinates (a closed form to test against)."""

    def predict(self, p, blocks, warm, iterations):
        uv = blocks[self.block] + p.distortion[..., 0]
        return uv, torch.ones(uv.shape[0], dtype=torch.bool)


def test_residuals_and_jacobian_follow_the_documented_layout():
    observed = torch.tensor([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]], dtype=F64)
    block = torch.tensor([0, 1, 1])
    tolerance = torch.full((len(NAMES),), float("inf"), dtype=F64)
    tolerance[NAMES.index("k1")] = 0.5
    problem = Shifted(thesis_setup1(), ["k1"], observed, block, torch.zeros(2, 2, dtype=F64), tolerance, sigma_px=2.0)
    assert problem.num_rig == 1 and problem.x0.tolist() == [0.0, 0.0, 0.0, 0.0, 0.0]
    x = torch.tensor([0.1, 1.0, 2.0, 3.0, 4.0], dtype=F64)  # k1, block 0 (u, v), block 1 (u, v)
    residuals = problem.residuals(x)
    predicted = torch.tensor([[1.1, 2.1], [3.1, 4.1], [3.1, 4.1]], dtype=F64)
    expected = torch.cat([((predicted - observed) / 2.0).reshape(-1), torch.tensor([0.1 / 0.5], dtype=F64)])
    torch.testing.assert_close(residuals, expected)
    jacobian = problem.jacobian(x)
    assert jacobian.shape == (7, 5)
    numeric = torch.stack([(problem.residuals(x + e) - problem.residuals(x - e)) / 2e-6
                           for e in torch.eye(5, dtype=F64) * 1e-6], 1)
    torch.testing.assert_close(jacobian, numeric, atol=1e-6, rtol=0)
    assert jacobian[:2, 3:].abs().sum() == 0  # block 1's unknowns do not move block 0's observation
    problem.active[1] = False  # an inactive observation: zero rows
    assert problem.residuals(x)[2:4].abs().sum() == 0 and problem.jacobian(x)[2:4].abs().sum() == 0
