"""Calibrated confidence: the probability that a depth of :class:`~prismstereo.classical.model.PrismStereo` is right.

A coarse-to-fine estimate carries more evidence about its own correctness than the final window's NCC alone:
whether the coarse level agreed, how rough the estimate is around the pixel (wrong matches in weak texture are
noisy, right ones follow the surface), how far the fine band moved from the coarse placement, how much texture
the reference window has, and whether the coarse level's thresholds rejected the pixel. A logistic
model of these features (:data:`FEATURES`) turns them into the probability that the pixel's depth is within
1 % of the truth:

    p = sigmoid(w . f + b)                                                      (logistic regression)

fitted on renders of this package with :func:`fit_confidence` (``benchmarks/fit_confidence.py`` regenerates
:data:`DEFAULT_WEIGHTS` and :data:`SMOOTHED_WEIGHTS`; the renders it uses are disjoint from the held-out scenes
of ``benchmarks/dense_depth.py``, which report the reliability curve: how often pixels with p >= c are wrong).
A model that smooths its estimate (:func:`~prismstereo.matching.postprocess.robust_mean`, weighted by p)
re-scores every pixel with a second logistic model of the evidence around it (:data:`SMOOTHED_FEATURES`: p,
the share of the window's confidence that agrees with its mean, the window's mean confidence, and the spread of
the smoothed estimates in the window: wrong estimates in weak texture and the band fattened along a depth edge sit
among estimates that jump, right ones on a surface whose estimates change smoothly):

    p' = sigmoid(w' . f' + b')
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.errors import OptionError, ShapeError, check_odd, check_shape
from prismstereo.matching.aggregate import box_std
from prismstereo.runtime import box_max, exporting

__all__ = [
    "DEFAULT_WEIGHTS",
    "FEATURES",
    "FITTED_PLACEMENT",
    "CLAMPED_WEIGHTS",
    "SMOOTHED_FEATURES",
    "SMOOTHED_WEIGHTS",
    "ConfidenceModel",
    "Threshold",
    "confidence_features",
    "confidence_threshold",
    "fit_confidence",
    "local_spread",
    "smoothed_features",
]

FEATURES: tuple[str, ...] = ("ncc", "coarse", "roughness", "offset", "texture", "rejected")
"""The feature channels of :func:`confidence_features`, in order."""

# fitted by benchmarks/fit_confidence.py (the last entry is the bias) on the default chain with its final band
# rejecting its edges (the script's --band-edges reject; the default model's clamped final band keeps these
# weights: docs/design.md, *How the model picks its defaults*, Confidence weights)
DEFAULT_WEIGHTS: tuple[float, ...] = (4.046, 2.069, -2.178, -1.673, 0.051, -0.093, -1.161)

SMOOTHED_FEATURES: tuple[str, ...] = ("confidence", "agreement", "support", "spread")
"""The feature channels of :func:`smoothed_features`, in order."""

# fitted by benchmarks/fit_confidence.py (the last entry is the bias), as DEFAULT_WEIGHTS
SMOOTHED_WEIGHTS: tuple[float, ...] = (0.197, 7.186, 6.694, -0.558, -8.889)

CLAMPED_WEIGHTS: tuple[tuple[float, ...], tuple[float, ...]] = (
    (2.528, 3.100, -5.274, -4.406, 0.156, 0.139, 0.463),
    (0.000, -0.525, 6.879, -0.950, -1.798),
)
"""(stage 1, stage 2) weights of models whose final band clamps its edges instead of rejecting them
(``band_edges='clamp'``, the ``'fast'`` preset: ``confidence_weights='clamped'``; fitted by
``benchmarks/fit_confidence.py --presets fast``): their wrong estimates agree with their neighbours more often,
and the default weights trusted them too much. In stage 2 the spread carries what the agreement did (the two
describe the same window; the fit leaves the agreement a small negative weight). The own-confidence weight of
stage 2 is held >= 0 as in every fit (a negative one makes more evidence at a pixel lower its confidence): it
comes out at 0."""

# the thresholds of the coarse level (the binned model of a pyramid) whose validity the features "coarse" and
# "rejected" describe: those of the renders DEFAULT_WEIGHTS were fitted on (the model's defaults), whatever the
# user's thresholds of a calibrated model
FITTED_PLACEMENT: dict[str, float] = {"min_confidence": 0.5, "min_uniqueness": 0.3, "reach_confidence": 0.9,
                                      "occlusion_tolerance": 0.01, "occluder_confidence": 0.8}

_ROUGHNESS_WINDOW = 5
_OFFSET_CAP = 3.0  # hypothesis steps; beyond the default bands
_TEXTURE_EPS = 1e-3


def confidence_features(
    ncc: torch.Tensor,
    coarse: torch.Tensor,
    s: torch.Tensor,
    s0: torch.Tensor,
    texture: torch.Tensor,
    step: float,
    rejected: torch.Tensor,
) -> torch.Tensor:
    """The features of :data:`FEATURES` per pixel.

    * ``ncc``: the final window's similarity (NCC for ZNCC), as given;
    * ``coarse``: the coarse level's similarity at the pixel (0 where it had no valid estimate), as given;
    * ``roughness``: log(1 + std of s / step over a 5 x 5 window);
    * ``offset``: |s - s0| / step, capped at 3 (how far the fine band moved from the coarse placement);
    * ``texture``: log(``texture`` + 1e-3);
    * ``rejected``: 1 where the coarse level's thresholds rejected the pixel (its band then lies around an
      estimate extended from valid neighbours, or around the coarse level's own), else 0.

    Args:
        ncc: (B, 1, H, W) in [0, 1].
        coarse: (B, 1, H, W) in [0, 1].
        s: (B, 1, H, W) final sweep coordinate.
        s0: (B, 1, H, W) the coarse placement of the band.
        texture: (B, 1, H, W) standard deviation of the reference's grey values over the cost window
            (:func:`~prismstereo.matching.aggregate.box_std`).
        step: hypothesis spacing in s (> 0).
        rejected: (B, 1, H, W) bool.

    Returns:
        (B, 6, H, W) features, dtype of ``s``.

    Example:
        >>> z = torch.zeros(1, 1, 8, 8)
        >>> confidence_features(z, z, z, z, z, 0.01, z.bool()).shape
        torch.Size([1, 6, 8, 8])
    """
    check_shape(s, ["B", 1, "H", "W"], "s")
    for name, t in (("ncc", ncc), ("coarse", coarse), ("s0", s0), ("texture", texture), ("rejected", rejected)):
        if t.shape != s.shape:
            raise ShapeError(f"{name} must have the shape of s {tuple(s.shape)}, got {tuple(t.shape)}")
    if not step > 0:
        raise OptionError(f"step must be > 0, got {step}")
    roughness = torch.log1p(box_std(s / step, _ROUGHNESS_WINDOW))
    offset = ((s - s0).abs() / step).clamp(max=_OFFSET_CAP)
    texture = torch.log(texture.to(s.dtype) + _TEXTURE_EPS)
    return torch.cat([ncc.to(s.dtype), coarse.to(s.dtype), roughness, offset, texture, rejected.to(s.dtype)], 1)


def local_spread(values: torch.Tensor, mask: torch.Tensor, window: int) -> torch.Tensor:
    """max - min of the ``values`` of the ``mask``ed pixels in a ``window`` x ``window`` box around every pixel
    (0 where the box holds none), by separable max pools.

    Args:
        values: (B, 1, H, W) finite values.
        mask: (B, 1, H, W) bool, the pixels that count.
        window: odd int >= 1.

    Returns:
        (B, 1, H, W) >= 0, dtype of ``values``.

    Example:
        >>> x = torch.tensor([[[[0.0, 0.0, 3.0, 3.0]]]]); m = torch.tensor([[[[True, True, True, False]]]])
        >>> local_spread(x, m, 3)[0, 0, 0].tolist()
        [0.0, 3.0, 3.0, 0.0]
    """
    check_shape(values, ["B", 1, "H", "W"], "values")
    if mask.shape != values.shape or mask.dtype != torch.bool:
        raise ShapeError(f"mask must be a bool tensor of the shape of values {tuple(values.shape)}, got "
                         f"{mask.dtype} {tuple(mask.shape)}")
    check_odd(window, "window")
    if window == 1:
        return torch.zeros_like(values)
    # unmasked pixels take the extreme of all values on the other side: they never set a box's max or min, and a
    # box without masked pixels gets max - min <= 0
    low, high = values.amin().detach(), values.amax().detach()
    top = box_max(torch.where(mask, values, low), window)
    bottom = -box_max(-torch.where(mask, values, high), window)
    return (top - bottom).clamp_min(0.0)


def smoothed_features(confidence: torch.Tensor, agreement: torch.Tensor, support: torch.Tensor,
                      spread: torch.Tensor) -> torch.Tensor:
    """The features of :data:`SMOOTHED_FEATURES` per pixel, after a
    :func:`~prismstereo.matching.postprocess.robust_mean` of the estimate weighted by ``confidence``: the pixel's
    own confidence, the share of its window's confidence that agrees with the window's mean
    (:class:`~prismstereo.matching.postprocess.RobustMean` ``agreement``), the window's mean confidence
    (``support``) and log(1 + ``spread``), the range of the smoothed estimates in the window in hypothesis steps
    (:func:`local_spread`).

    Args:
        confidence, agreement, support: (B, 1, H, W) in [0, 1].
        spread: (B, 1, H, W) >= 0.

    Returns:
        (B, 4, H, W) features, dtype of ``confidence``.

    Example:
        >>> z = torch.full((1, 1, 4, 4), 0.5)
        >>> smoothed_features(z, z, z, z).shape
        torch.Size([1, 4, 4, 4])
    """
    check_shape(confidence, ["B", 1, "H", "W"], "confidence")
    for name, t in (("agreement", agreement), ("support", support), ("spread", spread)):
        if t.shape != confidence.shape:
            raise ShapeError(f"{name} must have the shape of confidence {tuple(confidence.shape)}, got "
                             f"{tuple(t.shape)}")
    return torch.cat([confidence, agreement.to(confidence), support.to(confidence),
                      torch.log1p(spread.to(confidence).clamp_min(0.0))], 1)


class ConfidenceModel(nn.Module):
    """p = sigmoid(w . f + b) per pixel: the probability that a pixel's depth is within 1 % of the truth.

    Args:
        weights: len(names) + 1 numbers (the feature weights, then the bias); default :data:`DEFAULT_WEIGHTS`
            (:data:`SMOOTHED_WEIGHTS` with ``names=SMOOTHED_FEATURES``).
        names: the features, :data:`FEATURES` (:func:`confidence_features`) or :data:`SMOOTHED_FEATURES`
            (:func:`smoothed_features`).

    Example:
        >>> model = ConfidenceModel()
        >>> p = model(torch.zeros(2, len(FEATURES), 4, 4))
        >>> p.shape, bool(((p > 0) & (p < 1)).all())
        (torch.Size([2, 1, 4, 4]), True)
    """

    def __init__(self, weights: Sequence[float] | torch.Tensor | None = None,
                 names: tuple[str, ...] = FEATURES) -> None:
        super().__init__()
        if names not in (FEATURES, SMOOTHED_FEATURES):
            raise OptionError(f"names must be FEATURES {FEATURES} or SMOOTHED_FEATURES {SMOOTHED_FEATURES}, "
                              f"got {names!r}")
        if weights is None:
            weights = DEFAULT_WEIGHTS if names == FEATURES else SMOOTHED_WEIGHTS
        w = torch.as_tensor(weights, dtype=torch.float32).flatten()
        if w.numel() != len(names) + 1 or not bool(torch.isfinite(w).all()):
            raise OptionError(f"weights must be {len(names) + 1} finite numbers ({', '.join(names)}, bias), "
                              f"got {w.numel()}")
        self.names = names
        self.register_buffer("weight", w[:-1].view(1, -1, 1, 1))
        self.register_buffer("bias", w[-1:].view(1, 1, 1, 1))

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """(B, 1, H, W) probability from (B, len(names), H, W) features (:func:`confidence_features` or
        :func:`smoothed_features`)."""
        check_shape(features, ["B", len(self.names), "H", "W"], "features")
        weight, bias = self.weight.to(features), self.bias.to(features)
        if exporting():  # one MatMul (1, F) @ (B, F, H W): in onnxruntime cheaper than the multiply-adds below
            # (which split the features apart first) and than a 1 x 1 convolution (a blocked layout with reorders)
            b, f, h, w = features.shape
            return torch.sigmoid(torch.matmul(weight.view(1, f), features.flatten(2)).view(b, 1, h, w) + bias)
        # torch eager: one multiply-add per feature
        logit = bias + features[:, :1] * weight[:, :1]
        for i in range(1, features.shape[1]):
            logit = logit + features[:, i:i + 1] * weight[:, i:i + 1]
        return torch.sigmoid(logit)


def fit_confidence(features: torch.Tensor, correct: torch.Tensor, max_iter: int = 500,
                   nonnegative: Sequence[int] = ()) -> torch.Tensor:
    """Logistic regression of ``correct`` on ``features`` (maximum likelihood, L-BFGS, float64).

    Args:
        features: (N, F) samples (pixels of :func:`confidence_features`, F = len(FEATURES), or of
            :func:`smoothed_features`).
        correct: (N,) bool, the pixel's depth is within 1 % of the truth.
        max_iter: L-BFGS iterations.
        nonnegative: indices of features whose weight must be >= 0 (e.g. the pixel's own first-stage confidence
            in the second stage: more evidence at the pixel must not lower its confidence, which collinear
            features can make the unconstrained fit do). A weight that comes out negative is fixed at 0 and the
            others are fitted again, until none is (an active-set search; for one active constraint it is the
            constrained maximum, the likelihood being concave).

    Returns:
        (F + 1,) float64 weights, the bias last (:class:`ConfidenceModel`'s ``weights``).

    Raises:
        ShapeError: bad shapes. OptionError: ``correct`` has only one class, an index out of range.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> f = torch.randn(2000, len(FEATURES), generator=g)
        >>> y = torch.rand(2000, generator=g) < torch.sigmoid(2.0 * f[:, 0])
        >>> round(float(fit_confidence(f, y)[0]), 0)
        2.0
    """
    check_shape(features, ["N", "F"], "features")
    if correct.shape != features.shape[:1]:
        raise ShapeError(f"correct must be ({features.shape[0]},), got {tuple(correct.shape)}")
    y = correct.to(torch.float64)
    if y.min() == y.max():
        raise OptionError("correct must hold both correct and wrong pixels to fit a confidence")
    n_features = features.shape[1]
    if any(not isinstance(i, int) or not 0 <= i < n_features for i in nonnegative):
        raise OptionError(f"nonnegative must hold feature indices in [0, {n_features}), got {list(nonnegative)}")
    design = torch.cat([features.to(torch.float64), torch.ones_like(y).unsqueeze(1)], 1)
    fixed: set[int] = set()
    while True:
        free = [i for i in range(n_features + 1) if i not in fixed]
        w = torch.zeros(n_features + 1, dtype=torch.float64)
        w[free] = _logistic(design[:, free], y, max_iter)
        negative = [i for i in nonnegative if w[i] < 0]
        if not negative:
            return w
        fixed.update(negative)


def _logistic(design: torch.Tensor, y: torch.Tensor, max_iter: int) -> torch.Tensor:
    """Maximum-likelihood logistic weights of (N, K) ``design`` for (N,) targets ``y`` in {0, 1}."""
    w = torch.zeros(design.shape[1], dtype=torch.float64, requires_grad=True)
    opt = torch.optim.LBFGS([w], max_iter=max_iter, line_search_fn="strong_wolfe")

    def closure() -> torch.Tensor:
        opt.zero_grad()
        loss = F.binary_cross_entropy_with_logits(design @ w, y)
        loss.backward()
        return loss

    with torch.enable_grad():
        opt.step(closure)
    return w.detach()


class Threshold(NamedTuple):
    """The result of :func:`confidence_threshold`.

    Attributes:
        value: the lowest confidence that is kept (NaN when nothing can be kept).
        kept: how many pixels a threshold at ``value`` keeps.
    """

    value: float
    kept: int


def confidence_threshold(confidence: torch.Tensor, right: torch.Tensor, bad: float) -> Threshold:
    """The threshold on a confidence that keeps the most pixels with at most a share ``bad`` of them wrong: the
    largest set {confidence >= c} whose share of wrong pixels is <= ``bad`` (a threshold keeps all the pixels at a
    confidence or none of them).

    Args:
        confidence: (N,) confidences of pixels with a depth.
        right: (N,) bool, whether each depth is right (e.g. within 1 % of the truth).
        bad: the largest share of wrong pixels kept, in [0, 1).

    Returns:
        Threshold(value, kept).

    Raises:
        ShapeError: tensors that are not (N,) of one length, or ``right`` not bool. OptionError: ``bad`` outside
            [0, 1).

    Example:
        >>> c = torch.tensor([0.9, 0.8, 0.7, 0.6]); ok = torch.tensor([True, True, False, True])
        >>> confidence_threshold(c, ok, 0.3)  # 0.6 keeps all four, one of them wrong
        Threshold(value=0.6000000238418579, kept=4)
        >>> confidence_threshold(c, ok, 0.2).kept  # at 0.7 a third is wrong: only the first two
        2
    """
    check_shape(confidence, ["N"], "confidence")
    if right.shape != confidence.shape or right.dtype != torch.bool:
        raise ShapeError(f"right must be a bool tensor of confidence's shape {tuple(confidence.shape)}, got "
                         f"{right.dtype} {tuple(right.shape)}")
    if not 0.0 <= bad < 1.0:
        raise OptionError(f"bad must be in [0, 1), got {bad!r}")
    order = torch.argsort(confidence, descending=True, stable=True)
    c = confidence[order]
    wrong = (~right[order]).double().cumsum(0)
    count = torch.arange(1, len(order) + 1, dtype=torch.float64)
    cut = torch.ones_like(c, dtype=torch.bool)  # only between distinct confidences
    cut[:-1] = c[1:] < c[:-1]
    ok = (wrong <= bad * count) & cut
    if not ok.any():
        return Threshold(float("nan"), 0)
    k = int(ok.nonzero().max()) + 1
    return Threshold(float(c[k - 1]), k)
