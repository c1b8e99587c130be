"""Depth jobs on Ray (an optional extra: ``pip install prismstereo[ray]``): :func:`run`'s tasks on a Ray cluster
(``prismstereo depth INPUTS... --ray [ADDRESS]``), and :class:`DepthPredictor`, the model mapped over a Ray Dataset
of captures.

Each Ray worker is an actor holding one copy of the :class:`~prismstereo.jobs.runner.Runner` (the model or its
exported graph, shipped once through Ray's object store) on one CPU; the driver hands the captures (in batches)
and sequences to idle actors and gathers the reports. When an actor's process dies, the driver starts a new actor in
its place and gives it the dead one's unit again (up to :data:`RETRIES` times per unit; Ray's own ``max_restarts``
would keep the runner's reference as a constructor argument in the object store, which Ray reports as an error
for restartable actors). Files are renamed into place only when whole, so a retry rewrites them and a dead attempt
leaves at most a temporary file, which :func:`~prismstereo.jobs.run.run` removes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from prismstereo.errors import PrismStereoError
from prismstereo.jobs.plan import Task
from prismstereo.jobs.runner import Runner, TaskReport

__all__ = ["DepthPredictor", "RETRIES"]

RETRIES = 3  # replacements of a dead actor per unit of work


def _ray():
    try:
        import ray
    except ImportError as exc:
        raise PrismStereoError("--ray needs Ray: pip install 'prismstereo[ray]'") from exc
    return ray


class _Worker:
    """A Ray actor's runner (one CPU)."""

    def __init__(self, runner: Runner) -> None:
        runner.for_worker(1)
        self.runner = runner

    def work(self, unit: list[tuple[int, Task]], batch_size: int) -> list[tuple[int, TaskReport]]:
        from prismstereo.jobs.run import work

        return work(self.runner, unit, batch_size)


def run_on_ray(units: list[list[tuple[int, Task]]], runner: Runner, address: str | None, batch_size: int,
               deliver: Callable[[int, TaskReport], None]) -> int:
    """Run ``units`` on Ray actors (local instance without ``address``); returns the actor count."""
    ray = _ray()
    started = not ray.is_initialized()
    if started:
        ray.init(address=address, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        runner.prepare()
        shared = ray.put(runner)
        actor = ray.remote(num_cpus=1)(_Worker)
        count = max(1, min(int(ray.available_resources().get("CPU", 1)), len(units)))
        idle = [actor.remote(shared) for _ in range(count)]
        pending: dict[Any, tuple[Any, int]] = {}
        queue = list(reversed(range(len(units))))
        attempts = [0] * len(units)
        while queue or pending:
            while queue and idle:
                worker, u = idle.pop(), queue.pop()
                pending[worker.work.remote(units[u], batch_size)] = (worker, u)
            ready, _ = ray.wait(list(pending), num_returns=1)
            worker, u = pending.pop(ready[0])
            try:
                done = ray.get(ready[0])
                idle.append(worker)
            except ray.exceptions.RayActorError:  # its process died: a new actor in its place, the unit again
                idle.append(actor.remote(shared))
                attempts[u] += 1
                if attempts[u] <= RETRIES:
                    queue.append(u)
                    continue
                done = [(i, TaskReport(t.source, 0, 0, (), 0.0, "its Ray worker died")) for i, t in units[u]]
            except ray.exceptions.RayError as exc:
                idle.append(worker)
                done = [(i, TaskReport(t.source, 0, 0, (), 0.0, f"its Ray worker failed ({type(exc).__name__})"))
                        for i, t in units[u]]
            for i, rep in done:
                deliver(i, rep)
        return count
    finally:
        if started:
            ray.shutdown()


class DepthPredictor:
    """The depth model as a Ray Data batch function: ``dataset.map_batches(DepthPredictor, fn_constructor_kwargs=
    {"runner": runner}, concurrency=N, batch_size=B)`` over a dataset with an ``image`` column (e.g.
    ``ray.data.read_images(folder, include_paths=True)``): full sensor images (B, H, W) or (B, H, W, C), uint8,
    uint16 or float in [0, 1], RGB or grey. Adds ``depth`` (B, H, W_ref) float32 mm (NaN where invalid, or without a
    depth for a dense model) and ``confidence`` (B, H, W_ref) float32; the other columns pass through.

    Args:
        runner: a :class:`~prismstereo.jobs.runner.Runner` (its model or exported graph; run on one thread).

    Example:
        >>> from prismstereo.model import PrismStereo
        >>> predictor = DepthPredictor(Runner(PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0))))
        >>> out = predictor({"image": np.zeros((2, 48, 64), dtype=np.uint8)})
        >>> out["depth"].shape, out["depth"].dtype
        ((2, 48, 32), dtype('float32'))
    """

    def __init__(self, runner: Runner) -> None:
        runner.for_worker(1)
        self.runner = runner

    def __call__(self, batch: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        from prismstereo.io import to_grey

        images = np.stack(list(batch["image"])) if batch["image"].dtype == object else batch["image"]
        if images.ndim == 3:
            images = images[..., None]
        scale = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(images.dtype, 1.0)
        x = torch.from_numpy(np.ascontiguousarray(images)).permute(0, 3, 1, 2).to(torch.float32) / scale
        if x.shape[1] == 4:
            x = x[:, :3]
        x = to_grey(x)
        rig = self.runner.rig
        if tuple(x.shape[-2:]) != (rig.image_height, rig.image_width):
            raise PrismStereoError(f"images are {x.shape[-1]}x{x.shape[-2]} px but the rig's sensor is "
                                   f"{rig.image_width}x{rig.image_height} px")
        from prismstereo.threads import torch_threads

        with torch_threads(1):
            res = self.runner.depth(x)
        depth = torch.where(self.runner.written(res), res.depth, torch.full_like(res.depth, float("nan")))
        return {**batch, "depth": depth[:, 0].numpy().astype(np.float32),
                "confidence": res.confidence[:, 0].numpy().astype(np.float32)}
