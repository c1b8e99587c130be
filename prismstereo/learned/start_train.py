"""Train :class:`~prismstereo.learned.sweep_start.SweepStart` on :mod:`~prismstereo.learned.hybrid_data`'s rendered
captures (photographs and procedural surfaces through seven rig variants), on a CPU, resumable.

The variants are the renders' rigs and the same rigs binned 2 x 2 (half the sensor, twice the pixel pitch:
:func:`binned_rendered`). A step takes ``batch_size`` whole captures of one variant (drawn by its number of captures);
each half's
brightness and contrast is jittered again (x 0.8-1.25, +- 0.05) before the normalisation. The truth on the 8 x 8-binned
grid is the mean of the 4 x 4 blocks of the 2 x 2-binned truth, known where all 16 are known and agree within half a
hypothesis. Loss on the known pixels whose two hypotheses around the truth both sample the other half: the
cross-entropy of the softmax over the hypotheses against those two (weights linear in the distance), plus 0.3 times
the smooth L1 of the windowed expectation, in hypotheses. Adam, warm-up then cosine learning rate, gradients
clipped at 1.

A checkpoint (``<out>.ckpt``) is written every ``checkpoint_every`` steps; a run started again with the same options
continues from it, and its result is the uninterrupted run's.

The shipped ``weights/start.pt``: the command is in the comment below the imports, its options in its metadata.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import torch
import torch.nn.functional as F

from prismstereo.errors import check_int
from prismstereo.learned.checkpoint import Run, resume, run_steps
from prismstereo.learned.hybrid_data import Rendered, render_set, training_rigs
from prismstereo.learned.network import normalise_image
from prismstereo.learned.sweep_start import (
    LEARNED,
    SCALE,
    START_FORMAT,
    StartArchitecture,
    SweepStart,
    windowed_expectation,
)
from prismstereo.learned.train import TrainResult, warmup_cosine
from prismstereo.learned.weights import write_weights

__all__ = ["StartSet", "binned_rendered", "block_truth", "start_loss", "start_set", "train_start"]

# The shipped weights/start.pt (7 rig variants x 24 captures, the renders of weights/hybrid.pt's training, and the
# same rigs binned 2 x 2):
#   .venv/bin/prismstereo train --model start --cache .cache/hybrid --out prismstereo/learned/weights/start.pt


class StartSet(NamedTuple):
    """One rig variant's captures for the first stage.

    Attributes:
        name, rig, z_range_mm: the variant.
        grey: (N, 1, H/2, W/2) the 2 x 2-binned grey captures.
        truth: (N, 1, h, w) the true sweep coordinate on the 8 x 8-binned reference grid (0 where unknown).
        known: (N, 1, h, w) bool, where the truth is reliable (module docstring).
    """

    name: str
    rig: Any
    z_range_mm: tuple[float, float]
    grey: torch.Tensor
    truth: torch.Tensor
    known: torch.Tensor


def start_set(name: str, rendered: Rendered, rig: Any, z_range_mm: tuple[float, float],
              architecture: StartArchitecture | None = None) -> StartSet:
    """The first stage's truth of :func:`~prismstereo.learned.hybrid_data.render_set`'s captures of ``rig``, on the
    grid of its :class:`SweepStart` (module docstring).

    Example:
        >>> rendered = render_set("s", rig, (450.0, 1000.0), 2)  # doctest: +SKIP
        >>> data = start_set("s", rendered, rig, (450.0, 1000.0))  # doctest: +SKIP
    """
    model = SweepStart(rig, z_range_mm, architecture=architecture)
    known = rendered.known & torch.isfinite(rendered.truth)
    truth, reliable = block_truth(rendered.truth, known, SCALE // 2, model.step, tuple(model.covered_mask.shape[-2:]))
    return StartSet(name, rig, z_range_mm, rendered.grey, truth, reliable)


def block_truth(s: torch.Tensor, known: torch.Tensor, factor: int, step: float, size: tuple[int, int]
                ) -> tuple[torch.Tensor, torch.Tensor]:
    """True sweep coordinates on a grid ``factor`` times coarser: each block's mean, reliable where all its pixels
    are known and their values lie within half a ``step`` of each other.

    Args:
        s: (N, 1, H, W) true sweep coordinates (any value where not known).
        known: (N, 1, H, W) bool.
        factor: the block side.
        step: the spacing of the coarse grid's hypotheses in s.
        size: (h, w) of the coarse grid; blocks beyond the fine grid are unknown, fine pixels beyond it are cut.

    Returns:
        (truth, reliable): (N, 1, h, w) each, truth 0 where not reliable.

    Example:
        >>> s = torch.tensor([[0.1, 0.1, 0.5, 0.9]]).view(1, 1, 1, 4).expand(1, 1, 2, 4)
        >>> truth, reliable = block_truth(s, torch.ones(1, 1, 2, 4, dtype=torch.bool), 2, 0.5, (1, 2))
        >>> truth.flatten().tolist(), reliable.flatten().tolist()
        ([0.10000000149011612, 0.0], [True, False])
    """
    h, w = size
    filled = torch.where(known, s, torch.zeros_like(s))
    pad = (0, max(0, w * factor - filled.shape[-1]), 0, max(0, h * factor - filled.shape[-2]))
    filled = F.pad(filled, pad)[..., :h * factor, :w * factor]
    known = F.pad(known, pad)[..., :h * factor, :w * factor]
    blocks = F.unfold(filled, factor, stride=factor)  # (N, factor^2, h w)
    all_known = F.unfold(known.to(filled.dtype), factor, stride=factor).amin(1) > 0.5
    reliable = (all_known & (blocks.amax(1) - blocks.amin(1) < 0.5 * step)).view(-1, 1, h, w)
    return torch.where(reliable, blocks.mean(1).view(-1, 1, h, w), 0.0), reliable


def binned_rendered(rendered: Rendered) -> Rendered:
    """The captures of a rig seen through 2 x 2 binning (:meth:`~prismstereo.geometry.rig.BiPrismRig.binned`):
    a sensor of half the size and twice the pixel pitch, for free. Truth: the mean of 2 x 2 blocks, known where all
    four are (the first stage's truth then asks them to agree).

    Example:
        >>> half = binned_rendered(render_set("s", rig, (450.0, 1000.0), 2))  # doctest: +SKIP
    """
    known = rendered.known & torch.isfinite(rendered.truth)
    filled = torch.where(known, rendered.truth, torch.zeros_like(rendered.truth))
    h, w = filled.shape[-2] // 2 * 2, filled.shape[-1] // 2 * 2
    all_known = -F.max_pool2d(-known[..., :h, :w].to(filled.dtype), 2) > 0.5
    truth = torch.where(all_known, F.avg_pool2d(filled[..., :h, :w], 2), torch.nan)
    rays = -F.max_pool2d(-rendered.rays[..., :h, :w].to(filled.dtype), 2) > 0.5
    return Rendered(F.avg_pool2d(rendered.grey, 2), truth, all_known, rays)


def start_loss(model: SweepStart, image: torch.Tensor, truth: torch.Tensor, known: torch.Tensor) -> torch.Tensor:
    """The training loss of one batch (module docstring).

    Args:
        model: the first stage of the captures' rig and range.
        image: (B, 2, H/2, W/2) normalised binned captures.
        truth: (B, 1, h, w) true sweep coordinates on the 8 x 8-binned reference grid.
        known: (B, 1, h, w) bool, where the truth counts.

    Returns:
        () the loss.

    Example:
        >>> model = SweepStart(thesis_setup1().downscaled(2), (450.0, 1000.0))
        >>> truth, known = torch.zeros(1, 1, 48, 32), torch.ones(1, 1, 48, 32, dtype=torch.bool)
        >>> start_loss(model, torch.randn(1, 2, 192, 256), truth, known).shape
        torch.Size([])
    """
    scores = model.scores(image)
    d = scores.shape[1]
    position, known = model.truth_index(truth, known)  # fractional hypothesis index on the scores' grid
    known = known & (position >= 0) & (position <= d - 1)
    index = torch.arange(d, dtype=scores.dtype).view(1, -1, 1, 1)
    target = (1.0 - (index - position.clamp(0, d - 1)).abs()).clamp_min(0.0)  # the two neighbours, linear weights
    # a truth whose neighbouring hypotheses do not both sample the other half has no score to learn from
    sampled = (target * model.valid.to(target.dtype)).sum(1, keepdim=True) > 0.999
    known = known & sampled
    count = known.sum().clamp_min(1)
    ce = -(target * F.log_softmax(scores, 1).clamp_min(-100.0)).sum(1, keepdim=True)
    expected, _ = windowed_expectation(scores, index.flatten(), model.architecture.window)
    l1 = F.smooth_l1_loss(expected, position, reduction="none")  # in hypotheses
    return ((ce + 0.3 * l1) * known).sum() / count


def _jitter(grey: torch.Tensor, w_ref: int, gen: torch.Generator) -> torch.Tensor:
    """Each half's brightness and contrast changed (module docstring), then normalised."""
    b = grey.shape[0]
    gain = torch.exp(torch.empty(b, 1, 1, 2).uniform_(-0.223, 0.223, generator=gen))
    offset = torch.empty(b, 1, 1, 2).uniform_(-0.05, 0.05, generator=gen)
    column = (torch.arange(grey.shape[-1]) >= w_ref).long()
    out = grey * gain[..., column] + offset[..., column]
    return normalise_image(out.clamp(0, 1))


def _models(sets: list[StartSet], arch: StartArchitecture) -> list[SweepStart]:
    """One first stage per rig variant, all sharing the first one's learned layers."""
    models: list[SweepStart] = []
    for data in sets:
        model = SweepStart(data.rig, data.z_range_mm, architecture=arch)
        if models:
            for name in LEARNED:
                setattr(model, name, getattr(models[0], name))
        models.append(model)
    return models


def train_start(
    out_path: str | Path,
    *,
    steps: int = 3000,
    seed: int = 0,
    batch_size: int = 2,
    captures: int = 24,
    learning_rate: float = 2e-3,
    architecture: StartArchitecture | None = None,
    cache: str | Path | None = None,
    checkpoint_every: int = 100,
    progress: bool = True,
    sets: list[StartSet] | None = None,
) -> TrainResult:
    """Train the first stage from random initialisation (or from ``<out>.ckpt``) and write its weights.

    Args:
        out_path: weights file to write.
        steps: optimiser steps (>= 1).
        seed: seeds the initialisation, the data order and the rendered sets.
        batch_size: captures per step.
        captures: captures rendered per rig variant (ignored with ``sets``).
        learning_rate: Adam's peak learning rate.
        architecture: the hyper-parameters (default :class:`StartArchitecture` ()).
        cache: folder of the rendered sets (:func:`~prismstereo.learned.hybrid_data.render_set`).
        checkpoint_every: steps between checkpoints (0: none).
        progress: progress bars.
        sets: training sets to use instead of the rendered ones.

    Returns:
        TrainResult(losses, seconds, path).

    Raises:
        OptionError: bad ``steps``, ``batch_size`` or ``checkpoint_every``.

    Example:
        >>> result = train_start("start.pt", steps=2, cache=".cache/hybrid")  # doctest: +SKIP
    """
    for name, value, low in (("steps", steps, 1), ("batch_size", batch_size, 1),
                             ("checkpoint_every", checkpoint_every, 0)):
        check_int(value, name, low)
    arch = architecture or StartArchitecture()
    out_path = Path(out_path)
    torch.manual_seed(seed)
    if sets is None:
        sets = []
        for i, (name, rig, z_range) in enumerate(training_rigs()):
            rendered = render_set(name, rig, z_range, captures, seed=seed * 100 + i, cache=cache, progress=progress)
            sets.append(start_set(name, rendered, rig, z_range, arch))
            sets.append(start_set(f"{name} binned 2", binned_rendered(rendered), rig.binned(2), z_range, arch))
    models = _models(sets, arch)
    optimiser = torch.optim.Adam(models[0].parameters(), lr=learning_rate)  # the learned layers only
    run = Run(models[0], optimiser, warmup_cosine(optimiser, steps, max(1, min(100, steps // 10))),
               torch.Generator().manual_seed(seed), out_path.with_suffix(".ckpt"))
    out_path.parent.mkdir(parents=True, exist_ok=True)
    losses, first, seconds = resume(run, steps, arch)
    seconds = _optimise(run, models, sets, losses, first, seconds, arch, batch_size, checkpoint_every, progress)
    curve = [float(chunk.mean()) for chunk in losses.chunk(min(10, steps))]
    path = write_weights(out_path, START_FORMAT, arch, models[0].weights(), {
        "steps": steps, "seed": seed, "batch_size": batch_size, "captures": [int(d.grey.shape[0]) for d in sets],
        "variants": [d.name for d in sets], "final_loss": float(losses[-50:].mean()), "loss_curve": curve,
        "seconds": round(seconds, 1)})
    run.checkpoint.unlink(missing_ok=True)
    return TrainResult(losses, seconds, path)


def _optimise(run: Run, models: list[SweepStart], sets: list[StartSet], losses: torch.Tensor, first: int,
              seconds: float, arch: StartArchitecture, batch_size: int, checkpoint_every: int,
              progress: bool) -> float:
    """Steps ``first`` to the last (module docstring); returns ``seconds`` plus this run's wall time."""

    def loss_of(v: int, gen: torch.Generator) -> torch.Tensor:
        data, model = sets[v], models[v]
        pick = torch.randint(data.grey.shape[0], (batch_size,), generator=gen)
        image = _jitter(data.grey[pick], model.rig.binned(2).reference_width, gen)
        return start_loss(model, image, data.truth[pick], data.known[pick])

    counts = torch.tensor([float(d.grey.shape[0]) for d in sets])
    return run_steps(run, arch, losses, first, seconds, counts, loss_of, checkpoint_every=checkpoint_every,
                     progress=progress, desc="train start")
