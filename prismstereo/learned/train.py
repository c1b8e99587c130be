"""Train :class:`~prismstereo.learned.network.LearnedStereo` on this package's own renders, on a CPU, in minutes.

Captures come from :func:`~prismstereo.learned.data.training_set` on the rig binned by ``downscale`` (rendering
dominates; the set is cached). Each step draws ``batch_size`` captures, a random band of rows (a crop is the
same rig with fewer rows and the principal point moved, so the sweep stays exact) and one of three searches:
the range with ``num_hypotheses``, the range with 4/3 as many, and a wider range (0.9 z_min to 1.2 z_max) with
4/3 as many. Binning by 2 halves the sweep's length in pixels, so half of the full-resolution hypothesis count
keeps the spacing per hypothesis the full-resolution model sees; the variants teach the aggregation other
spacings. Brightness, contrast and the balance of the two halves are jittered.

Loss on the co-visible reference pixels whose true depth lies in the searched range, in units of the
hypothesis index (linear in 1/Z): smooth L1 of the refined index plus half that of the upsampled regression,
plus 0.2 times the binary cross-entropy of the confidence against |depth error| < 1 % on every valid
reference ray (pixels the other half does not see are negatives). Adam, cosine learning rate, seeded.

The shipped ``weights/thesis_setup1.pt`` was made with ``prismstereo train`` (the command: the comment below the
imports; the file's metadata holds the options, the loss curve and the time; ``benchmarks/learned.py`` measures
the weights against the classical model).
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import NamedTuple

import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

from prismstereo.errors import OptionError, RigError
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.learned.data import TrainingSet, training_set
from prismstereo.learned.network import Architecture, LearnedStereo

__all__ = ["TrainResult", "depth_loss", "train", "warmup_cosine"]

# The shipped weights/thesis_setup1.pt (80 captures at 512 x 384, 900 steps of 4 captures; one torch thread, as
# two threads on 2 shared cores compete with any other process for them):
#   OMP_NUM_THREADS=1 .venv/bin/prismstereo train --rig thesis_setup1 --steps 900 --cache .cache/learned \
#       --out prismstereo/learned/weights/thesis_setup1.pt
# Its loss curve and training time are in the file's metadata; half the steps left the weights clearly less
# accurate at full resolution (benchmarks/learned.py measures them).


class TrainResult(NamedTuple):
    """:func:`train`'s result.

    Attributes:
        losses: (steps,) float64 training loss of every step.
        seconds: wall time of the optimisation (without rendering).
        path: the weights file written.
    """

    losses: torch.Tensor
    seconds: float
    path: Path


class _Search(NamedTuple):
    model: LearnedStereo
    row: int  # first row of the crop in the training captures


def _searches(model: LearnedStereo, rig: BiPrismRig, z_range: tuple[float, float], d: int) -> list[_Search]:
    """Row bands x (range, hypothesis count) variants, all sharing ``model``'s CNNs."""
    s = model.architecture.scale
    h = rig.image_height
    crop = max((h // 2) // s * s, s)
    cx, cy = rig.principal_point
    rows = sorted({round(r * (h - crop) / 3 / s) * s for r in range(4)})
    lo, hi = z_range
    more = max(d * 4 // 3, d + 1)
    variants = [((lo, hi), d), ((lo, hi), more), ((0.9 * lo, 1.2 * hi), more)]
    out = []
    for row in rows:
        try:
            band = rig.replace(image_height=crop, principal_point=(cx, cy - row))
        except RigError:  # the principal point would leave the band
            continue
        if band.reference_width != rig.reference_width:
            continue
        for zr, n in variants:
            out.append(_Search(model.for_rig(band, zr, num_hypotheses=n, with_match=False), row))
    return out or [_Search(model, 0)]


def warmup_cosine(optimiser: torch.optim.Optimizer, steps: int, warmup: int) -> torch.optim.lr_scheduler.LambdaLR:
    """The trainers' learning rate: a linear warm-up over ``warmup`` steps times a cosine decay over ``steps`` to 5 %
    of the peak.

    Example:
        >>> optimiser = torch.optim.Adam([torch.zeros(1, requires_grad=True)], lr=1.0)
        >>> warmup_cosine(optimiser, 100, 10).get_last_lr()
        [0.1]
    """
    return torch.optim.lr_scheduler.LambdaLR(
        optimiser, lambda k: min(1.0, (k + 1) / warmup) * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * k / steps))))


def depth_loss(model: LearnedStereo, image: torch.Tensor, depth: torch.Tensor,
               covisible: torch.Tensor) -> torch.Tensor:
    """The training loss of one batch (module docstring): smooth-L1 of the refined and the coarse hypothesis index
    against the truth's, and the confidence's cross-entropy against "within 1 %", over the co-visible pixels with a
    true depth in the range.

    Args:
        model: the model being trained.
        image: (B, C, H, W) captures in [0, 1].
        depth: (B, 1, H, W_ref) true depth (mm; NaN where unknown).
        covisible: (B, 1, H, W_ref) bool, pixels the other half sees.

    Returns:
        () the loss.

    Example:
        >>> from prismstereo.learned.network import LearnedStereo
        >>> model = LearnedStereo(thesis_setup1().downscaled(8), (450.0, 900.0), num_hypotheses=8, weights=None)
        >>> depth_loss(model, torch.rand(1, 1, 96, 128), torch.full((1, 1, 96, 64), 600.0),
        ...            torch.ones(1, 1, 96, 64, dtype=torch.bool)).shape
        torch.Size([])
    """
    parts = model._parts(image)
    d = model.num_hypotheses
    truth = model.depth_to_index(depth)
    known = covisible & torch.isfinite(depth) & (truth >= 0) & (truth <= d - 1) & parts.inside
    truth = torch.where(known, truth, torch.zeros_like(truth))
    count = known.sum().clamp_min(1)
    fine = (F.smooth_l1_loss(parts.index, truth, reduction="none") * known).sum() / count
    coarse = (F.smooth_l1_loss(parts.coarse, truth, reduction="none") * known).sum() / count
    with torch.no_grad():
        estimate = model.index_to_depth(parts.index)
        correct = known & ((estimate - depth).abs() < 0.01 * depth)
    rays = parts.inside.expand_as(correct)
    bce = F.binary_cross_entropy_with_logits(parts.logit, correct.to(parts.logit.dtype), reduction="none")
    confidence = (bce * rays).sum() / rays.sum().clamp_min(1)
    return fine + 0.5 * coarse + 0.2 * confidence


def _jitter(image: torch.Tensor, w_ref: int, gen: torch.Generator) -> torch.Tensor:
    """Random gain and offset per image, and a brightness ratio between the halves."""
    b = image.shape[0]
    gain = 0.6 + 0.8 * torch.rand(b, 1, 1, 1, generator=gen)
    offset = 0.2 * torch.rand(b, 1, 1, 1, generator=gen) - 0.1
    halves = torch.ones(b, 1, 1, image.shape[-1])
    halves[..., w_ref:] = (0.9 + 0.2 * torch.rand(b, 1, 1, 1, generator=gen))
    return ((image - 0.5) * gain + 0.5 + offset).mul(halves).clamp(0.0, 1.0)


def train(
    rig: BiPrismRig,
    out_path: str | Path,
    *,
    steps: int = 900,
    seed: int = 0,
    batch_size: int = 4,
    z_range_mm: tuple[float, float] = (450.0, 1000.0),
    num_hypotheses: int = 24,
    downscale: int = 2,
    captures: int = 80,
    learning_rate: float = 2e-3,
    architecture: Architecture | None = None,
    rig_name: str = "custom",
    progress: bool = True,
    cache: str | Path | None = None,
    data: TrainingSet | None = None,
) -> TrainResult:
    """Train LearnedStereo from random initialisation and write its weights to ``out_path``.

    Args:
        rig: the full-resolution rig; training renders through ``rig.downscaled(downscale)``.
        out_path: weights file to write (:meth:`LearnedStereo.save`; parent folders are created).
        steps: optimiser steps (>= 1).
        seed: seeds the initialisation (``torch.manual_seed``), the data order and the jitter (a
            ``torch.Generator``) and the rendered set.
        batch_size: captures per step.
        z_range_mm: the depths rendered and searched.
        num_hypotheses: D of the training searches (at ``downscale`` 2, half the full-resolution D).
        downscale: binning of the training rig (1 = full resolution).
        captures: captures rendered (ignored when ``data`` is given).
        learning_rate: Adam's peak learning rate (linear warm-up over min(20, steps / 10) steps, cosine decay to
            5 % of it).
        architecture: the network's hyper-parameters (default :class:`Architecture` ()).
        rig_name: stored in the weights file's metadata.
        progress: progress bars (rendering and steps).
        cache: folder for the rendered set (see :func:`~prismstereo.learned.data.training_set`).
        data: a set to use instead of rendering one (its captures must be of the training rig).

    Returns:
        TrainResult(losses, seconds, path).

    Raises:
        OptionError: bad ``steps``, ``batch_size``, ``downscale`` or a ``data`` set of another sensor size.

    Example:
        >>> result = train(thesis_setup1().downscaled(8), "w.pt", steps=2)  # doctest: +SKIP
    """
    for name, value in (("steps", steps), ("batch_size", batch_size), ("downscale", downscale)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise OptionError(f"{name} must be an int >= 1, got {value!r}")
    gen = torch.Generator().manual_seed(seed)
    small = rig if downscale == 1 else rig.downscaled(downscale)
    if data is None:
        data = training_set(small, captures, seed=seed, z_range_mm=z_range_mm, cache=cache, progress=progress)
    if tuple(data.image.shape[-2:]) != (small.image_height, small.image_width):
        raise OptionError(f"data captures are {tuple(data.image.shape[-2:])}, the training rig "
                          f"{small.image_height}x{small.image_width}")
    arch = architecture or Architecture()
    torch.manual_seed(seed)  # the initialisation: LearnedStereo(..., weights=None) right after it is the same
    model = LearnedStereo(small, z_range_mm, num_hypotheses=num_hypotheses, scale=arch.scale, weights=None,
                          architecture=arch, with_match=False)
    searches = _searches(model, small, tuple(float(z) for z in z_range_mm), num_hypotheses)
    losses, seconds = _optimise(model, searches, data, small.reference_width, steps=steps, batch_size=batch_size,
                                learning_rate=learning_rate, gen=gen, progress=progress)
    curve = [float(chunk.mean()) for chunk in losses.chunk(min(10, steps))]  # the loss curve, in 10 chunks
    path = model.save(out_path, rig=rig_name, steps=steps, seed=seed, batch_size=batch_size,
                      z_range_mm=tuple(float(z) for z in z_range_mm), num_hypotheses=num_hypotheses,
                      downscale=downscale, captures=int(data.image.shape[0]), final_loss=float(losses[-20:].mean()),
                      loss_curve=curve, seconds=round(seconds, 1))
    return TrainResult(losses, seconds, path)


def _optimise(model: LearnedStereo, searches: list[_Search], data: TrainingSet, w_ref: int, *, steps: int,
              batch_size: int, learning_rate: float, gen: torch.Generator,
              progress: bool) -> tuple[torch.Tensor, float]:
    """The optimisation of :func:`train` (module docstring): Adam with :func:`warmup_cosine`, each step a random
    search, ``batch_size`` random captures cropped to its rows and jittered. Returns the (steps,) float64 losses and
    the loop's wall time (s)."""
    optimiser = torch.optim.Adam(model.parameters(), lr=learning_rate)
    schedule = warmup_cosine(optimiser, steps, max(1, min(20, steps // 10)))
    losses = torch.zeros(steps, dtype=torch.float64)
    model.train()
    start = time.perf_counter()
    bar = tqdm(range(steps), desc="train", disable=not progress)
    for step in bar:
        search = searches[int(torch.randint(len(searches), (1,), generator=gen))]
        pick = torch.randint(data.image.shape[0], (batch_size,), generator=gen)
        rows = slice(search.row, search.row + search.model.rig.image_height)
        image = _jitter(data.image[pick][..., rows, :], w_ref, gen)
        loss = depth_loss(search.model, image, data.depth[pick][..., rows, :], data.covisible[pick][..., rows, :])
        optimiser.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        optimiser.step()
        schedule.step()
        losses[step] = loss.item()
        bar.set_postfix(loss=f"{losses[max(0, step - 19):step + 1].mean():.3f}")
    return losses, time.perf_counter() - start
