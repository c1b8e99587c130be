"""Resumable training runs: a checkpoint restores the module, optimiser, schedule and generator."""

import dataclasses
from pathlib import Path

import torch
from torch import nn

from prismstereo.learned.checkpoint import Run, resume, run_steps, save_checkpoint


@dataclasses.dataclass(frozen=True)
class Arch:
    width: int = 3


def _run(path: Path, seed: int) -> Run:
    torch.manual_seed(seed)
    module = nn.Linear(Arch().width, 1)
    optimiser = torch.optim.Adam(module.parameters(), lr=0.1)
    schedule = torch.optim.lr_scheduler.LambdaLR(optimiser, lambda step: 1.0 / (1 + step))
    return Run(module, optimiser, schedule, torch.Generator().manual_seed(seed), path)


def _step(run: Run) -> None:
    x = torch.randn(4, 3, generator=run.gen)
    loss = run.module(x).square().mean()
    run.optimiser.zero_grad()
    loss.backward()
    run.optimiser.step()
    run.schedule.step()


def test_a_resumed_run_continues_where_it_stopped(tmp_path):
    path = tmp_path / "w.ckpt"
    run = _run(path, 0)
    losses = torch.zeros(5, dtype=torch.float64)
    fresh_losses, first, seconds = resume(run, 5, Arch())  # no checkpoint yet
    assert (first, seconds) == (0, 0.0) and torch.equal(fresh_losses, losses)
    for _ in range(2):
        _step(run)
    losses[:2] = torch.tensor([1.0, 2.0])
    save_checkpoint(run, Arch(), losses, 2, 3.5)
    again = _run(path, 1)  # another initialisation, optimiser and generator: all replaced
    restored, first, seconds = resume(again, 5, Arch())
    assert (first, seconds) == (2, 3.5) and torch.equal(restored, losses)
    for a, b in zip(run.module.parameters(), again.module.parameters(), strict=True):
        assert torch.equal(a, b)
    _step(run)
    _step(again)  # the same batch, learning rate and Adam moments: the same step
    for a, b in zip(run.module.parameters(), again.module.parameters(), strict=True):
        assert torch.equal(a, b)
    # a checkpoint of other steps or another architecture starts afresh
    for steps, arch in ((6, Arch()), (5, Arch(width=4))):
        fresh = _run(path, 2)
        losses, first, _ = resume(fresh, steps, arch)
        assert first == 0 and losses.shape == (steps,) and not losses.any()


def test_run_steps_draws_sets_by_their_captures_and_an_interrupted_run_ends_the_same(tmp_path):
    drawn: list[int] = []

    def loss_of(v: int, gen: torch.Generator, run: Run) -> torch.Tensor:
        drawn.append(v)
        return run.module(torch.randn(4, 3, generator=gen) + v).square().mean()

    counts = torch.tensor([0.0, 3.0, 1.0])  # set 0 has no captures: never drawn
    whole = _run(tmp_path / "a.ckpt", 0)
    losses = torch.zeros(6, dtype=torch.float64)
    run_steps(whole, Arch(), losses, 0, 0.0, counts, lambda v, g: loss_of(v, g, whole), checkpoint_every=0,
              progress=False, desc="test")
    assert losses.all() and 0 not in drawn and len(drawn) == 6 and not (tmp_path / "a.ckpt").exists()
    # a checkpoint every four steps (none after the last); a new run resumes from it
    again = _run(tmp_path / "c.ckpt", 0)
    losses_again = torch.zeros(6, dtype=torch.float64)
    run_steps(again, Arch(), losses_again, 0, 0.0, counts, lambda v, g: loss_of(v, g, again), checkpoint_every=4,
              progress=False, desc="test")
    assert torch.equal(losses_again, losses)  # checkpoints change nothing
    stopped = _run(tmp_path / "c.ckpt", 5)
    resumed, first, seconds = resume(stopped, 6, Arch())
    assert first == 4 and torch.equal(resumed[:4], losses[:4])
    run_steps(stopped, Arch(), resumed, first, seconds, counts, lambda v, g: loss_of(v, g, stopped),
              checkpoint_every=4, progress=False, desc="test")
    assert torch.equal(resumed, losses)  # resumed from step 4: the uninterrupted run's losses

