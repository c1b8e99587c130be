"""Train :class:`~prismstereo.learned.hybrid.HybridStereo`'s refinement on :mod:`~prismstereo.learned.hybrid_data`
captures, on a CPU, resumable.

The classical estimate of every capture is computed once before training (it does not learn), so a step only runs
the refinement: ``batch_size`` captures of one rig variant, a random crop of the reference half aligned to the
classical grid, touching the sensor's top or bottom edge in a third of the steps and its left or right edge in a
third (the other half stays whole for the warp), every stage. Loss, in steps of the sweep (<= 1 px at 1/2):
smooth L1 of each stage's s (upsampled to 1/2) against the truth on the known blocks (the last stage weighted 1,
earlier ones 0.5), plus 0.3 times the binary cross-entropy of the last confidence against "depth within 1 %" on every
block with a true depth (blocks the other half does not see are negatives). Adam, warm-up then cosine learning rate,
gradients clipped at 1. After training, :func:`validity_threshold` picks the confidence above which a depth is
valid: the lowest that keeps the training captures' valid depths at most :data:`VALID_BAD` wrong (stored in the
weights' metadata as ``valid_confidence``).

A checkpoint (``<out>.ckpt``: the CNNs, optimiser, schedule, random states and losses) is written every
``checkpoint_every`` steps; a run started again with the same options continues from it, and the result is the
same as an uninterrupted run's.

The shipped ``weights/hybrid.pt``: the command is in the comment below the imports, its options in its metadata.
"""

from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.epipolar.sweep import sweep_to_depth
from prismstereo.errors import check_int
from prismstereo.learned.checkpoint import Run, resume, run_steps
from prismstereo.learned.hybrid import HybridArchitecture, HybridStereo, RefinementInputs
from prismstereo.learned.hybrid_data import HybridSet, training_rigs, training_sets
from prismstereo.learned.train import TrainResult, warmup_cosine

__all__ = ["VALID_BAD", "correct_depth", "hybrid_loss", "train_hybrid", "validity_threshold"]

VALID_BAD = 0.03  # the share of wrong depths the calibrated validity threshold allows on the training captures

# The shipped weights/hybrid.pt (7 rig variants x 24 captures, 6000 steps, two torch threads, on the estimates of the
# shipped weights/start.pt, trained first by the command in prismstereo.learned.start_train; its time: metadata; the
# command then trains the confidence head, prismstereo.learned.confidence_train):
#   .venv/bin/prismstereo train --model hybrid --cache .cache/hybrid --out prismstereo/learned/weights/hybrid.pt
# weights/hybrid_block.pt (the stages for the classical block start) came from the same command with one torch thread
# (OMP_NUM_THREADS=1) and --start classical, before the learned start was the default.


def hybrid_loss(model: HybridStereo, inputs: RefinementInputs, truth: torch.Tensor, known: torch.Tensor,
                rays: torch.Tensor, window: tuple[int, int] = (0, 0), size: tuple[int, int] | None = None
                ) -> torch.Tensor:
    """The training loss of one batch (module docstring).

    Args:
        model: the model of the captures' rig and range.
        inputs: the classical estimate of a crop from row, column ``window`` of its grid on.
        truth: (B, 1, h, w) true sweep coordinates on the 2 x 2-binned grid (NaN where unknown).
        known, rays: (B, 1, h, w) bool, blocks with a reliable truth / with a true depth.
        window, size: the crop (:meth:`HybridStereo.refine`).

    Returns:
        () the loss.

    Example:
        >>> model = HybridStereo(thesis_setup1().downscaled(2), (450.0, 1000.0), weights=None)
        >>> h, w = model.half.image_height, model.half.reference_width
        >>> inputs = model.initial(torch.rand(1, 1, 384, 512))  # the whole capture: no window
        >>> ones = torch.ones(1, 1, h, w, dtype=torch.bool)
        >>> hybrid_loss(model, inputs, torch.zeros(1, 1, h, w), ones, ones).shape
        torch.Size([])
    """
    target = torch.where(known, truth, torch.zeros_like(truth))
    count = known.sum().clamp_min(1)
    outputs = model.refine(inputs, window, size)
    loss = inputs.s.new_zeros(())
    for i, (s, _) in enumerate(outputs):
        weight = 1.0 if i == len(outputs) - 1 else 0.5
        error = F.smooth_l1_loss(s / model.step, target / model.step, reduction="none")
        loss = loss + weight * (error * known).sum() / count
    s, logit = outputs[-1]
    with torch.no_grad():
        correct = correct_depth(model, s, truth, known)
    bce = F.binary_cross_entropy_with_logits(logit, correct.to(logit.dtype), reduction="none")
    return loss + 0.3 * (bce * rays).sum() / rays.sum().clamp_min(1)


def correct_depth(model: HybridStereo, s: torch.Tensor, truth: torch.Tensor, known: torch.Tensor) -> torch.Tensor:
    """The confidence's target: (B, 1, h, w) bool, known blocks whose depth from ``s`` (B, 1, h, w) is within 1 % of
    the truth's (``truth`` the true s, ``known`` bool, both (B, 1, h, w)).

    Example:
        >>> model = HybridStereo(thesis_setup1().downscaled(4), (450.0, 1000.0), weights=None)
        >>> s = torch.zeros(1, 1, 2, 2); known = torch.tensor([[[[True, True], [False, True]]]])
        >>> correct_depth(model, s, s + torch.tensor([0.0, 0.5]), known).tolist()
        [[[[True, False], [False, False]]]]
    """
    z_range = torch.tensor(model.z_range, dtype=s.dtype)
    true_depth = sweep_to_depth(torch.where(known, truth, torch.zeros_like(truth)), z_range)
    return known & ((sweep_to_depth(s, z_range) - true_depth).abs() < 0.01 * true_depth)


def _batch(model: HybridStereo, data: HybridSet, pick: torch.Tensor, crop: tuple[int, int], gen: torch.Generator):
    """A step's crop: the classical estimate's crop (``crop`` in 2 x 2-binned pixels, aligned to the classical grid),
    its window and size, and the truth maps of the crop."""
    f = model.architecture.block // 2
    hk, wk = data.s.shape[-2:]
    ch, cw = min(crop[0] // f, hk), min(crop[1] // f, wk)
    # the sensor's edges (where the classical level leaves a margin) in a third of the crops along each axis
    r, c = (int(torch.randint(n + 1, (1,), generator=gen)) for n in (hk - ch, wk - cw))
    r, c = ({0: 0, 1: n}.get(int(torch.randint(6, (1,), generator=gen)), x) for x, n in ((r, hk - ch), (c, wk - cw)))
    inputs = RefinementInputs(data.image[pick], *(t[pick][..., r:r + ch, c:c + cw] for t in (data.s, data.confidence,
                                                                                            data.covered)))
    rows, cols = slice(r * f, (r + ch) * f), slice(c * f, (c + cw) * f)
    truth = tuple(t[pick][..., rows, cols] for t in (data.truth, data.known, data.rays))
    return inputs, truth, (r, c), (ch * f, cw * f)


def train_hybrid(
    out_path: str | Path,
    *,
    steps: int = 6000,
    seed: int = 0,
    batch_size: int = 8,
    crop: tuple[int, int] = (96, 128),
    captures: int = 24,
    learning_rate: float = 2e-3,
    architecture: HybridArchitecture | None = None,
    cache: str | Path | None = None,
    checkpoint_every: int = 250,
    progress: bool = True,
    sets: list[HybridSet] | None = None,
) -> TrainResult:
    """Train the refinement from random initialisation (or from ``<out>.ckpt``) and write its weights.

    Args:
        out_path: weights file to write (:meth:`HybridStereo.save`).
        steps: optimiser steps (>= 1).
        seed: seeds the initialisation, the data order and the rendered sets.
        batch_size: captures per step.
        crop: (rows, columns) of the 2 x 2-binned reference half per capture.
        captures: captures rendered per rig variant (ignored with ``sets``).
        learning_rate: Adam's peak learning rate.
        architecture: the CNNs' hyper-parameters (default :class:`HybridArchitecture` ()).
        cache: folder of the rendered sets.
        checkpoint_every: steps between checkpoints (0: none).
        progress: progress bars.
        sets: training sets to use instead of :func:`~prismstereo.learned.hybrid_data.training_sets` (each with
            the rig and range of its captures).

    Returns:
        TrainResult(losses, seconds, path).

    Raises:
        OptionError: bad ``steps``, ``batch_size`` or ``checkpoint_every``.

    Example:
        >>> result = train_hybrid("hybrid.pt", steps=2)  # doctest: +SKIP
    """
    for name, value, low in (("steps", steps, 1), ("batch_size", batch_size, 1), ("checkpoint_every",
                                                                                   checkpoint_every, 0)):
        check_int(value, name, low)
    arch = architecture or HybridArchitecture()
    out_path = Path(out_path)
    torch.manual_seed(seed)
    models = _models(sets, arch)
    if sets is None:
        sets = training_sets(captures, seed=seed, cache=cache, models=models, progress=progress)
    stages = nn.ModuleList([models[0].stages, models[0].quarter_stages])
    optimiser = torch.optim.Adam(stages.parameters(), lr=learning_rate)
    run = Run(stages, optimiser, warmup_cosine(optimiser, steps, max(1, min(50, steps // 10))),
               torch.Generator().manual_seed(seed), out_path.with_suffix(".ckpt"))
    out_path.parent.mkdir(parents=True, exist_ok=True)
    losses, first, seconds = resume(run, steps, arch)
    seconds = _optimise(run, models, sets, losses, first, seconds, arch=arch, batch_size=batch_size, crop=crop,
                        checkpoint_every=checkpoint_every, progress=progress)
    valid_confidence = validity_threshold(models, sets)
    curve = [float(chunk.mean()) for chunk in losses.chunk(min(10, steps))]
    path = models[0].save(out_path, steps=steps, seed=seed, batch_size=batch_size, crop=list(crop),
                          captures=[int(d.s.shape[0]) for d in sets], variants=[d.name for d in sets],
                          final_loss=float(losses[-50:].mean()), loss_curve=curve, seconds=round(seconds, 1),
                          valid_confidence=valid_confidence)
    run.checkpoint.unlink(missing_ok=True)
    return TrainResult(losses, seconds, path)


def _models(sets: list[HybridSet] | None, arch: HybridArchitecture) -> list[HybridStereo]:
    """One untrained model per rig variant (of ``sets``, else :func:`~prismstereo.learned.hybrid_data.training_rigs`),
    all sharing the first one's refinement stages."""
    models: list[HybridStereo] = []
    variants = [(d.name, d.rig, d.z_range_mm) for d in sets] if sets is not None else training_rigs()
    for _, rig, z_range in variants:
        model = HybridStereo(rig, z_range, weights=None, architecture=arch)
        if models:
            model.stages, model.quarter_stages = models[0].stages, models[0].quarter_stages
        models.append(model)
    return models


def _optimise(run: Run, models: list[HybridStereo], sets: list[HybridSet], losses: torch.Tensor, first: int,
              seconds: float, *, arch: HybridArchitecture, batch_size: int, crop: tuple[int, int],
              checkpoint_every: int, progress: bool) -> float:
    """Steps ``first`` to the last of :func:`train_hybrid` (module docstring), each on a rig variant drawn by its
    number of captures, writing ``losses`` and a checkpoint every ``checkpoint_every`` steps. Returns ``seconds`` plus
    this run's wall time."""

    def loss_of(v: int, gen: torch.Generator) -> torch.Tensor:
        data, model = sets[v], models[v]
        pick = torch.randint(data.s.shape[0], (batch_size,), generator=gen)
        inputs, truth, window, size = _batch(model, data, pick, crop, gen)
        return hybrid_loss(model, inputs, *truth, window, size)

    counts = torch.tensor([float(d.s.shape[0]) for d in sets])
    return run_steps(run, arch, losses, first, seconds, counts, loss_of, checkpoint_every=checkpoint_every,
                     progress=progress, desc="train hybrid")


def validity_threshold(models: list[HybridStereo], sets: list[HybridSet], bad: float = VALID_BAD) -> float:
    """The validity threshold of trained refinement stages: the lowest confidence that keeps at most a share ``bad``
    of the depths it keeps wrong, over every capture of ``sets`` (photographs and procedural surfaces, each set
    refined whole by its own model). A depth is right where its block is known and within 1 % of the truth, wrong
    elsewhere on the blocks with a true depth: the confidence's training target.

    Args:
        models: one model per set (of its rig and range), sharing the stages.
        sets: the training sets.
        bad: the share of wrong depths allowed.

    Returns:
        The threshold (1.0 if no threshold keeps the share; the model then calls nothing valid).

    Example:
        >>> validity_threshold(models, sets)  # the shipped weights' training sets  # doctest: +SKIP
        0.733
    """
    from prismstereo.matching.confidence import confidence_threshold

    confidence, right = [], []
    with torch.no_grad():
        for model, data in zip(models, sets, strict=True):
            for pick in torch.arange(data.s.shape[0]).split(4):
                inputs = RefinementInputs(*(t[pick] for t in (data.image, data.s, data.confidence, data.covered)))
                s, logit = model.refine(inputs)[-1]
                rays = data.rays[pick]
                confidence.append(torch.sigmoid(logit)[rays])
                right.append(correct_depth(model, s, data.truth[pick], data.known[pick])[rays])
    threshold = confidence_threshold(torch.cat(confidence), torch.cat(right), bad).value
    return 1.0 if threshold != threshold else round(threshold, 4)
