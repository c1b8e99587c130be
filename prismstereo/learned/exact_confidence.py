"""The exact chain's confidence: the last learned stage's confidence re-scored with what the exact stage found.

The refinement's confidence sees the learned estimate's own inputs: 3 x 3 absolute differences at five offsets
around it. The exact last stage (:mod:`~prismstereo.learned.exact_stage`) measures more: the NCC of a 5 x 5 window
on the exact sweep at its fit, whether the fit agreed with the estimate and how far it lay from it. Where a photograph's
texture is weak, or where the other half cannot see the point (an occlusion whose fattened foreground depth the
learned estimate carries), those tell a wrong depth from a right one that the learned logit ranks alike.

:class:`ConfidenceHead` is a per-pixel MLP on :func:`exact_features` (six maps on the stages' grid):

1. the last learned stage's confidence logit (clipped to +-10); the head adds its output to it (a residual: a head
   whose output layer is zero keeps the learned confidence);
2. the band's NCC at its fit (:attr:`~prismstereo.learned.exact_stage.ExactEvidence.similarity`);
3. 1 where the fit replaced the estimate;
4. the fit's distance from the estimate in the band's steps (clipped at 3);
5. the spread of the final s over 5 x 5 pixels (its standard deviation in steps, clipped at 5): neighbours that
   disagree;
6. the reference's texture: the grey standard deviation over 5 x 5 pixels (x 20, clipped at 3).

It is trained after the refinement, on the same renders, against "within 1 % of the true depth" with the pixels the
other half cannot see counted as wrong (:mod:`~prismstereo.learned.confidence_train`); the weights file holds it as
``head.*`` and its calibrated validity threshold as ``exact_valid_confidence``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.errors import ShapeError, check_shape
from prismstereo.learned.exact_stage import ExactEvidence
from prismstereo.matching.aggregate import box_filter

__all__ = ["FEATURES", "HEAD_CHANNELS", "ConfidenceHead", "exact_features", "load_head"]

FEATURES = ("logit", "similarity", "taken", "move", "spread", "texture")
"""The head's input maps, in order (module docstring)."""
HEAD_CHANNELS = 16
"""Channels of the head's hidden layers."""
LOGIT_CLIP, MOVE_CLIP, SPREAD_CLIP, TEXTURE_SCALE, TEXTURE_CLIP = 10.0, 3.0, 5.0, 20.0, 3.0


def exact_features(evidence: ExactEvidence, logit: torch.Tensor, step: float) -> torch.Tensor:
    """The head's inputs (:data:`FEATURES`) from the exact stage's evidence and the last learned logit.

    Args:
        evidence: :meth:`~prismstereo.learned.exact_stage.ExactStage.evidence`, (B, 1, h, w) maps.
        logit: (B, 1, h, w) the last learned stage's confidence logit.
        step: a step of s on the stages' grid (the spread's unit).

    Returns:
        (B, 6, h, w).

    Raises:
        ShapeError: maps of different shapes.

    Example:
        >>> from prismstereo.learned.exact_stage import ExactEvidence
        >>> ones = torch.ones(1, 1, 8, 8)
        >>> exact_features(ExactEvidence(ones, ones, ones, ones, ones), ones, 0.01).shape
        torch.Size([1, 6, 8, 8])
    """
    check_shape(logit, ["B", 1, "H", "W"], "logit")
    for name, t in zip(evidence._fields, evidence, strict=True):
        if t.shape != logit.shape:
            raise ShapeError(f"evidence.{name} {tuple(t.shape)} must have the logit's shape {tuple(logit.shape)}")
    s, ref = evidence.s, evidence.reference
    # both standard deviations from one box filter of the maps and their squares (floored before the root: a flat
    # window's gradient is 0, not infinite)
    mean_s, square_s, mean_r, square_r = box_filter(torch.cat([s, s * s, ref, ref * ref], 1), 5).split(1, 1)
    spread = (square_s - mean_s * mean_s).clamp_min(1e-12).sqrt() / step
    texture = (square_r - mean_r * mean_r).clamp_min(1e-12).sqrt() * TEXTURE_SCALE
    return torch.cat([logit.clamp(-LOGIT_CLIP, LOGIT_CLIP), evidence.similarity, evidence.taken,
                      evidence.move.clamp(max=MOVE_CLIP), spread.clamp(max=SPREAD_CLIP),
                      texture.clamp(max=TEXTURE_CLIP)], 1)


class ConfidenceHead(nn.Module):
    """The re-scoring network (module docstring): a per-pixel MLP, two hidden 1 x 1 convolutions with ReLUs and a
    1 x 1 output added to the learned logit. The spread and texture features already summarise 5 x 5 windows; 3 x 3
    convolutions over the maps ranked the held-out photographs no better and cost ten times the arithmetic.

    Args:
        channels: the hidden layers' channels.

    Example:
        >>> head = ConfidenceHead()
        >>> head(torch.zeros(2, len(FEATURES), 16, 12)).shape
        torch.Size([2, 1, 16, 12])
    """

    def __init__(self, channels: int = HEAD_CHANNELS) -> None:
        super().__init__()
        self.first = nn.Conv2d(len(FEATURES), channels, 1)
        self.hidden = nn.Conv2d(channels, channels, 1)
        self.out = nn.Conv2d(channels, 1, 1)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """The confidence logit, (B, 1, h, w), of :func:`exact_features` ``features`` (B, 6, h, w).

        Raises:
            ShapeError: not (B, 6, h, w).
        """
        check_shape(features, ["B", len(FEATURES), "H", "W"], "features")
        return self.out(F.relu(self.hidden(F.relu(self.first(features))))) + features[:, :1]


def load_head(state: dict[str, torch.Tensor]) -> ConfidenceHead | None:
    """The head held by a hybrid weights file's tensors (its ``head.*`` entries), None if it holds none.

    Raises:
        WeightsError: ``head.*`` tensors that do not fit :class:`ConfidenceHead`.

    Example:
        >>> load_head(ConfidenceHead(channels=4).state_dict()) is None  # keys without the file's "head." prefix
        True
        >>> load_head({f"head.{k}": v for k, v in ConfidenceHead(channels=4).state_dict().items()}).out.in_channels
        4
    """
    from prismstereo.learned.weights import WeightsError, state_part

    part = state_part(state, "head")
    if not part:
        return None
    try:
        head = ConfidenceHead(channels=int(part["first.weight"].shape[0]))
        head.load_state_dict(part)
    except (KeyError, RuntimeError) as exc:
        raise WeightsError(f"the confidence head's weights do not fit ConfidenceHead: {exc}") from exc
    return head
