"""depth_regression: soft-argmax in inverse depth, masking of invalid hypotheses, the confidence (mass within one
hypothesis of the expected index), float64 gradcheck and errors."""

import pytest
import torch

from prismstereo.epipolar.grids import depth_hypotheses
from prismstereo.epipolar.sweep import sweep_to_depth
from prismstereo.errors import OptionError, ShapeError
from prismstereo.nn import DepthRegression, depth_regression

pytestmark = pytest.mark.usefixtures("one_thread")

DEPTHS = depth_hypotheses(400.0, 1000.0, 9)


def _cost(batch=2, seed=0, dtype=torch.float64):
    gen = torch.Generator().manual_seed(seed)
    return torch.randn(batch, 9, 5, 6, generator=gen, dtype=dtype)


def test_shapes_and_regression_in_inverse_depth():
    cost = _cost()
    out = depth_regression(cost, DEPTHS, temperature=0.7)
    assert isinstance(out, DepthRegression) and out.depth.shape == out.confidence.shape == (2, 1, 5, 6)
    # uniform in 1/Z: the depth at the expected sweep coordinate (not the expected depth)
    prob = torch.softmax(cost / 0.7, 1)
    s = (prob * torch.linspace(-1.0, 1.0, 9, dtype=torch.float64).view(1, -1, 1, 1)).sum(1, keepdim=True)
    torch.testing.assert_close(out.depth, sweep_to_depth(s, torch.tensor([400.0, 1000.0], dtype=torch.float64)))
    assert float((out.depth - (prob * DEPTHS.view(1, -1, 1, 1)).sum(1, keepdim=True)).max()) < 0


def test_peak_between_two_hypotheses():
    """Equal scores at hypotheses 3 and 4, nothing elsewhere: the inverse depth halfway, all mass within reach."""
    cost = torch.full((1, 9, 1, 1), -50.0, dtype=torch.float64)
    cost[0, 3:5] = 0.0
    out = depth_regression(cost, DEPTHS)
    expected = 2.0 / (1.0 / DEPTHS[3] + 1.0 / DEPTHS[4])
    torch.testing.assert_close(out.depth.flatten(), expected.view(1))
    assert float(out.confidence) == pytest.approx(1.0, abs=1e-12)


def test_confidence_definition_and_bounds():
    flat = depth_regression(torch.zeros(1, 9, 2, 2, dtype=torch.float64), DEPTHS)
    # uniform: expected index 4, hypotheses 3, 4, 5 within one index
    torch.testing.assert_close(flat.confidence, torch.full((1, 1, 2, 2), 3 / 9, dtype=torch.float64))
    out = depth_regression(_cost(seed=1) * 5, DEPTHS)
    assert float(out.confidence.min()) >= 0 and float(out.confidence.max()) <= 1 + 1e-12
    sharp = torch.zeros(1, 9, 1, 1, dtype=torch.float64)
    sharp[0, 6] = 100.0
    assert float(depth_regression(sharp, DEPTHS).confidence) == pytest.approx(1.0)


def test_invalid_hypotheses_are_left_out():
    cost = _cost(batch=1)
    valid = torch.ones(9, 5, 6, dtype=torch.bool)
    valid[:3] = False
    spoiled = cost.clone()
    spoiled[:, :3] = 1e6  # would win everywhere if it counted
    masked = depth_regression(spoiled, DEPTHS, valid)
    reference = depth_regression(cost[:, 3:], DEPTHS[3:])
    torch.testing.assert_close(masked.depth, reference.depth)
    batched = depth_regression(spoiled, DEPTHS, valid.unsqueeze(0))  # (B, D, h, w) masks too
    torch.testing.assert_close(batched.depth, masked.depth)


def test_pixel_without_valid_hypothesis():
    valid = torch.ones(9, 5, 6, dtype=torch.bool)
    valid[:, 0, 0] = False
    out = depth_regression(_cost(), DEPTHS, valid)
    assert torch.isfinite(out.depth).all() and torch.isfinite(out.confidence).all()
    assert float(out.confidence[:, 0, 0, 0].abs().max()) == 0.0
    torch.testing.assert_close(out.depth[:, 0, 0, 0], (9.0 / (1.0 / DEPTHS).sum()).expand(2))  # uniform


def test_gradcheck():
    cost = _cost(batch=1).requires_grad_(True)
    valid = torch.rand(9, 5, 6, generator=torch.Generator().manual_seed(1)) > 0.3
    f = lambda c: depth_regression(c, DEPTHS, valid, temperature=0.8)  # noqa: E731
    assert torch.autograd.gradcheck(f, (cost,), eps=1e-6, atol=1e-6)


def test_float32_depths_follow_the_cost_dtype():
    out = depth_regression(_cost(dtype=torch.float32), DEPTHS)
    assert out.depth.dtype == out.confidence.dtype == torch.float32


@pytest.mark.parametrize(
    ("call", "error", "match"),
    [
        (lambda: depth_regression(torch.zeros(9, 5, 6), DEPTHS), ShapeError, r"cost must have shape \(B, D, H, W\)"),
        (lambda: depth_regression(torch.zeros(1, 8, 5, 6), DEPTHS), ShapeError, "depths has 9 hypotheses"),
        (lambda: depth_regression(torch.zeros(1, 9, 5, 6), DEPTHS.view(3, 3)), ShapeError, "depths must have shape"),
        (lambda: depth_regression(torch.zeros(1, 9, 5, 6), DEPTHS, torch.ones(9, 5, 6)), ShapeError, "bool tensor"),
        (lambda: depth_regression(torch.zeros(1, 9, 5, 6), DEPTHS, torch.ones(9, 6, 5, dtype=torch.bool)),
         ShapeError, "valid must be"),
        (lambda: depth_regression(torch.zeros(2, 9, 5, 6), DEPTHS, torch.ones(3, 9, 5, 6, dtype=torch.bool)),
         ShapeError, "valid must be"),
        (lambda: depth_regression(torch.zeros(1, 9, 5, 6), DEPTHS, temperature=0.0), OptionError, "temperature"),
        (lambda: depth_regression(torch.zeros(1, 9, 5, 6), DEPTHS, temperature=float("inf")), OptionError,
         "temperature"),
    ],
)
def test_errors(call, error, match):
    with pytest.raises(error, match=match):
        call()
