"""Resumable training runs: the state a checkpoint keeps, shared by the hybrid's and the first stage's trainers
(:mod:`prismstereo.learned.hybrid_train`, :mod:`prismstereo.learned.start_train`).

A run is the trained module, its optimiser and learning-rate schedule, the generator that draws its batches and the
checkpoint's path (``<out>.ckpt``); :func:`take_step` is one step of it and :func:`run_steps` the steps of a run, each
on a training set drawn by its number of captures. :func:`save_checkpoint` writes them with the losses so far, the
next step and the seconds spent; :func:`resume` loads them into a run built with the same options, so that a run
stopped and started again ends with the uninterrupted run's result. A checkpoint of other steps or another
architecture is ignored.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import torch
from torch import nn
from tqdm.auto import tqdm

__all__ = ["Run", "resume", "run_steps", "save_checkpoint", "take_step"]


class Run(NamedTuple):
    """A training run's state that a checkpoint saves (besides the losses and the time), and the checkpoint's path.

    Example:
        >>> module = nn.Linear(2, 1)
        >>> optimiser = torch.optim.Adam(module.parameters())
        >>> run = Run(module, optimiser, torch.optim.lr_scheduler.LambdaLR(optimiser, lambda step: 1.0),
        ...           torch.Generator().manual_seed(0), Path("w.ckpt"))
    """

    module: nn.Module
    optimiser: torch.optim.Optimizer
    schedule: torch.optim.lr_scheduler.LRScheduler
    gen: torch.Generator
    checkpoint: Path


def save_checkpoint(run: Run, architecture: Any, losses: torch.Tensor, step: int, seconds: float) -> None:
    """Write ``run``'s state to its checkpoint: the module, optimiser, schedule and generator, the (steps,)
    ``losses``, the next ``step`` and the ``seconds`` spent, under ``architecture`` (a dataclass) and the step count.

    Example:
        >>> save_checkpoint(run, architecture, losses, step + 1, seconds)  # doctest: +SKIP
    """
    torch.save({"steps": int(losses.shape[0]), "architecture": dataclasses.asdict(architecture),
                "module": run.module.state_dict(), "optimiser": run.optimiser.state_dict(),
                "schedule": run.schedule.state_dict(), "generator": run.gen.get_state(), "losses": losses,
                "step": step, "seconds": seconds}, run.checkpoint)


def resume(run: Run, steps: int, architecture: Any) -> tuple[torch.Tensor, int, float]:
    """The (steps,) losses, the first step to run and the seconds spent: from the run's checkpoint when it is of the
    same ``steps`` and ``architecture`` (its states are loaded into ``run``), else zeros, 0 and 0.

    Example:
        >>> losses, first, seconds = resume(run, 100, architecture)  # doctest: +SKIP
    """
    if run.checkpoint.is_file():
        state = torch.load(run.checkpoint, weights_only=True)
        if state.get("steps") == steps and state.get("architecture") == dataclasses.asdict(architecture):
            run.module.load_state_dict(state["module"])
            run.optimiser.load_state_dict(state["optimiser"])
            run.schedule.load_state_dict(state["schedule"])
            run.gen.set_state(state["generator"])
            return state["losses"], state["step"], state["seconds"]
    return torch.zeros(steps, dtype=torch.float64), 0, 0.0


def take_step(run: Run, loss: torch.Tensor, clip: float = 1.0) -> float:
    """One optimiser step of ``run`` on ``loss`` (gradients clipped to norm ``clip``, then the schedule); the loss.

    Example:
        >>> losses[step] = take_step(run, loss)  # doctest: +SKIP
    """
    run.optimiser.zero_grad()
    loss.backward()
    torch.nn.utils.clip_grad_norm_(run.module.parameters(), clip)
    run.optimiser.step()
    run.schedule.step()
    return loss.item()


def run_steps(run: Run, architecture: Any, losses: torch.Tensor, first: int, seconds: float, counts: torch.Tensor,
              loss_of: Callable[[int, torch.Generator], torch.Tensor], *, checkpoint_every: int, progress: bool,
              desc: str) -> float:
    """Steps ``first`` to the last of ``run``: each draws a training set by ``counts`` (its captures) from the run's
    generator, takes :func:`take_step` on ``loss_of(set, generator)`` and writes ``losses``; a checkpoint every
    ``checkpoint_every`` steps (0: none). Returns ``seconds`` plus this call's wall time.

    Example:
        >>> seconds = run_steps(run, arch, losses, first, seconds, counts, loss_of, checkpoint_every=100,
        ...                     progress=False, desc="train")  # doctest: +SKIP
    """
    steps = losses.shape[0]
    run.module.train()
    start = time.perf_counter()
    bar = tqdm(range(first, steps), desc=desc, disable=not progress, initial=first, total=steps)
    for step in bar:
        v = int(torch.multinomial(counts, 1, generator=run.gen))
        losses[step] = take_step(run, loss_of(v, run.gen))
        bar.set_postfix(loss=f"{losses[max(0, step - 49):step + 1].mean():.3f}")
        if checkpoint_every and (step + 1) % checkpoint_every == 0 and step + 1 < steps:
            save_checkpoint(run, architecture, losses, step + 1, seconds + time.perf_counter() - start)
    return seconds + time.perf_counter() - start
