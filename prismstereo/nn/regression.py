"""Differentiable depth from a cost volume over depth hypotheses: soft-argmax in inverse depth.

With p_d = softmax_d(C_d / T) over the D hypotheses (higher cost = better match, as a correlation volume),
the depth is regressed in inverse depth, the coordinate the plane sweep is uniform in (s linear in 1/Z, thesis
ch. 4 / :mod:`prismstereo.epipolar.sweep`):

    1 / Z = sum_d p_d / Z_d,

so for hypotheses uniform in 1/Z it is exactly the depth at the expected sweep coordinate (and at the expected
index d_hat = sum_d p_d d). Averaging Z itself would bias the estimate toward the far, sparsely sampled end.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch

from prismstereo.errors import OptionError, ShapeError, check_shape

__all__ = ["DepthRegression", "depth_regression"]


class DepthRegression(NamedTuple):
    """:func:`depth_regression`'s result, (B, 1, h, w) each.

    Attributes:
        depth: Z (mm), 1 / sum_d p_d / Z_d.
        confidence: in [0, 1], the probability mass of the hypotheses within one index of the expected index
            d_hat (those d with |d - d_hat| <= 1: two or three of them); 0 where no hypothesis is valid.
    """

    depth: torch.Tensor
    confidence: torch.Tensor


def depth_regression(
    cost: torch.Tensor,
    depths: torch.Tensor,
    valid: torch.Tensor | None = None,
    temperature: float = 1.0,
) -> DepthRegression:
    """Soft-argmax depth and its confidence from a (B, D, h, w) volume (larger = more likely).

    p = softmax over D of cost / ``temperature``, with the hypotheses that are not ``valid`` left out (their
    probability is exactly 0). A pixel without any valid hypothesis gets the uniform distribution over all D
    (a finite depth, the harmonic mean of ``depths``) and confidence 0. Differentiable w.r.t. ``cost``
    (the confidence's window |d - d_hat| <= 1 is chosen without gradients; the mass inside it has them).
    Exports to ONNX (Softmax, Where with a scalar, reductions).

    Args:
        cost: (B, D, h, w) scores, e.g. :class:`~prismstereo.nn.cost_volume.PrismCostVolume`'s correlation.
        depths: (D,) hypotheses Z_d (mm), e.g. the volume's ``depths`` (uniform in 1/Z).
        valid: optional (D, h, w) or (B, D, h, w) bool, e.g. the volume's ``valid``.
        temperature: T > 0; smaller is closer to the arg-max.

    Returns:
        DepthRegression(depth, confidence), (B, 1, h, w) each, dtype of ``cost``.

    Raises:
        ShapeError: shapes that disagree. OptionError: temperature not a finite number > 0.

    Example:
        >>> depths = 1.0 / torch.linspace(1 / 400.0, 1 / 1000.0, 5)
        >>> cost = torch.tensor([0.0, 0.0, 10.0, 0.0, 0.0]).view(1, 5, 1, 1)
        >>> out = depth_regression(cost, depths, temperature=0.1)
        >>> round(out.depth.item(), 1), round(out.confidence.item(), 3), out.depth.shape
        (571.4, 1.0, torch.Size([1, 1, 1, 1]))
    """
    check_shape(cost, ["B", "D", "H", "W"], "cost")
    check_shape(depths, ["D"], "depths")
    d = cost.shape[1]
    if depths.shape[0] != d:
        raise ShapeError(f"depths has {depths.shape[0]} hypotheses, the cost volume {d}")
    if isinstance(temperature, bool) or not isinstance(temperature, (int, float)) or not (
            0 < temperature < math.inf):
        raise OptionError(f"temperature must be a finite number > 0, got {temperature!r}")
    logits = cost / temperature
    if valid is not None:
        ok = isinstance(valid, torch.Tensor) and valid.dtype == torch.bool and valid.dim() in (3, 4)
        ok = ok and tuple(valid.shape[-3:]) == tuple(cost.shape[1:])
        ok = ok and (valid.dim() == 3 or valid.shape[0] in (1, cost.shape[0]))
        if not ok:
            got = f"{valid.dtype} {tuple(valid.shape)}" if isinstance(valid, torch.Tensor) else type(valid).__name__
            raise ShapeError(f"valid must be a bool tensor of shape (D, h, w) or (B, D, h, w), cost is "
                             f"{tuple(cost.shape)}, got {got}")
        # invalid hypotheses: the lowest finite logit, so exp(. - max) is exactly 0 beside any valid one, and
        # a pixel without valid hypotheses gets a uniform (finite) distribution instead of NaN
        logits = torch.where(valid, logits, logits.new_tensor(torch.finfo(logits.dtype).min))
    prob = torch.softmax(logits, dim=1)
    inverse = (1.0 / depths.to(cost)).view(1, -1, 1, 1)
    depth = 1.0 / (prob * inverse).sum(1, keepdim=True)
    index = torch.arange(d, device=cost.device).to(cost.dtype).view(1, -1, 1, 1)
    expected = (prob * index).sum(1, keepdim=True)
    near = ((index - expected.detach()).abs() <= 1.0).to(cost.dtype)
    confidence = (prob * near).sum(1, keepdim=True)
    if valid is not None:
        confidence = confidence * valid.any(dim=-3, keepdim=True).to(cost.dtype)
    return DepthRegression(depth, confidence)
