"""Depth jobs on Ray (an optional extra: ``pip install prismstereo[ray]``): :class:`RayCluster`, the executor that
runs a job's units on Ray actors (``prismstereo depth INPUTS... --ray [ADDRESS]``), and :class:`DepthMapper`, the
predictor mapped over a Ray Dataset of captures.

Each Ray worker is an actor holding one copy of the :class:`~prismstereo.jobs.pipeline.Pipeline` (its predictor's
torch model or graphs' paths, shipped once through Ray's object store) on one CPU; the driver hands the captures
(in batches) and sequences to idle actors and gathers the reports. When an actor's process dies, the driver starts a
new actor in its place and gives it the dead one's unit again (up to :data:`RETRIES` times per unit; Ray's own
``max_restarts`` would keep the pipeline's reference as a constructor argument in the object store, which Ray reports
as an error for restartable actors). Files are renamed into place only when whole, so a retry rewrites them and a
dead attempt leaves at most a temporary file, which :func:`~prismstereo.jobs.run.run` removes.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
import torch

from prismstereo.conventions import to_grey
from prismstereo.errors import PrismStereoError
from prismstereo.jobs.executors import Deliver, Tick, Unit, work
from prismstereo.jobs.pipeline import Pipeline, TaskReport
from prismstereo.quiet import c_stderr_silenced
from prismstereo.threads import torch_threads

__all__ = ["DepthMapper", "RAY_CONNECT_SECONDS", "RETRIES", "RayCluster"]

RETRIES = 3  # replacements of a dead actor per unit of work
RAY_CONNECT_SECONDS = 10  # how long RayCluster.check tries a cluster (unless RAY_gcs_server_port_wait_time_s is set)


def _check_port(address: str | None, timeout: float) -> None:
    """A PrismStereoError unless ``address`` (HOST:PORT or ray://HOST:PORT; None and 'auto' are Ray's to find)
    accepts a TCP connection within ``timeout`` s: a refused or unroutable address fails here, not after Ray's
    retries."""
    import socket

    if address in (None, "auto"):
        return
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise PrismStereoError(f"a Ray address is 'auto', 'local', HOST:PORT or ray://HOST:PORT, got {address!r}")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except OSError as exc:
        reason = "no answer" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
        raise PrismStereoError(f"cannot connect to the Ray cluster at {address}: {reason} within {timeout:g} s"
                               ) from None


def _ray():
    try:
        import ray
    except ImportError as exc:
        raise PrismStereoError("--ray needs Ray: pip install 'prismstereo[ray]'") from exc
    return ray


class _Worker:
    """A Ray actor's pipeline (one CPU)."""

    def __init__(self, pipeline: Pipeline) -> None:
        self.pipeline = pipeline.for_process(1)

    def work(self, unit: Unit, batch_size: int) -> list[tuple[int, TaskReport]]:
        return work(self.pipeline, unit, batch_size)


class RayCluster:
    """Ray actors, one CPU each (the module docstring): a local instance, or the cluster at ``address``.

    Args:
        address: None or 'local' (a local instance), or a cluster's address ('auto', 'ray://host:10001').

    Example:
        >>> RayCluster().address is None
        True
    """

    def __init__(self, address: str | None = None) -> None:
        self.address = None if address in (None, "local") else address
        self._started = False  # connected by check(), to be shut down by run()

    def check(self, timeout: int = RAY_CONNECT_SECONDS) -> None:
        """Fail fast: connect now (before a model is built), trying for about ``timeout`` seconds (a local instance
        is started); :meth:`run` then uses this connection.

        Raises:
            PrismStereoError: Ray is not installed, or the cluster cannot be reached (one line).

        Example:
            >>> RayCluster("10.255.255.1:6379").check(2)  # doctest: +SKIP
            Traceback (most recent call last):
            ...
            prismstereo.errors.PrismStereoError: cannot connect to the Ray cluster at 10.255.255.1:6379 ...
        """
        ray = _ray()
        if ray.is_initialized():
            return
        _check_port(self.address, min(timeout, 5))
        # Ray retries the cluster's GCS once a second for RAY_gcs_server_port_wait_time_s (default 20)
        wait = os.environ.setdefault("RAY_gcs_server_port_wait_time_s", str(timeout))
        try:
            with c_stderr_silenced():  # its C++ client logs every retry on stderr
                ray.init(address=self.address, include_dashboard=False, log_to_driver=False,
                         configure_logging=False)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise PrismStereoError(f"cannot connect to the Ray cluster at {self.address or 'local'} within "
                                   f"{wait} s: {first}") from None
        self._started = True

    def run(self, units: list[Unit], pipeline: Pipeline, batch_size: int, deliver: Deliver, tick: Tick) -> int:
        """Run ``units`` on Ray actors (:class:`~prismstereo.jobs.executors.Executor`); returns the actor count."""
        ray = _ray()
        started = self._started or not ray.is_initialized()
        if not ray.is_initialized():
            self.check()
        self._started = False
        try:
            return _run_actors(ray, units, pipeline, batch_size, deliver, tick)
        finally:
            if started:
                ray.shutdown()


def _run_actors(ray: Any, units: list[Unit], pipeline: Pipeline, batch_size: int, deliver: Deliver,
                tick: Tick) -> int:
    """Hand ``units`` to idle actors, replacing dead ones (the module docstring); returns the actor count."""
    shared = ray.put(pipeline)
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
        for i, report in done:
            deliver(i, report)
            tick(report.written)
    return count


class DepthMapper:
    """The depth model as a Ray Data batch function: ``dataset.map_batches(DepthMapper, fn_constructor_kwargs=
    {"pipeline": pipeline}, concurrency=N, batch_size=B)`` over a dataset with an ``image`` column (e.g.
    ``ray.data.read_images(folder, include_paths=True)``): full sensor images (B, H, W) or (B, H, W, C), uint8,
    uint16 or float in [0, 1], RGB or grey. Adds ``depth`` (B, H, W_ref) float32 mm (NaN where invalid, or without a
    depth for a dense model) and ``confidence`` (B, H, W_ref) float32; the other columns pass through.

    Args:
        pipeline: a :class:`~prismstereo.jobs.pipeline.Pipeline` (its predictor, on one core; its write options'
            ``dense``).

    Example:
        >>> from prismstereo.models import build_model
        >>> from prismstereo.predictor import Predictor
        >>> model = build_model(thesis_setup1().downscaled(16), z_range=(400.0, 700.0))
        >>> mapper = DepthMapper(Pipeline(Predictor(model)))
        >>> out = mapper({"image": np.zeros((2, 48, 64), dtype=np.uint8)})
        >>> out["depth"].shape, out["depth"].dtype
        ((2, 48, 32), dtype('float32'))
    """

    def __init__(self, pipeline: Pipeline) -> None:
        self.pipeline = pipeline.for_process(1)

    def __call__(self, batch: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        images = np.stack(list(batch["image"])) if batch["image"].dtype == object else batch["image"]
        if images.ndim == 3:
            images = images[..., None]
        scale = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(images.dtype, 1.0)
        x = torch.from_numpy(np.ascontiguousarray(images)).permute(0, 3, 1, 2).to(torch.float32) / scale
        if x.shape[1] == 4:
            x = x[:, :3]
        x = to_grey(x)
        rig = self.pipeline.rig
        if tuple(x.shape[-2:]) != (rig.image_height, rig.image_width):
            raise PrismStereoError(f"images are {x.shape[-1]}x{x.shape[-2]} px but the rig's sensor is "
                                   f"{rig.image_width}x{rig.image_height} px")
        with torch_threads(self.pipeline.threads.torch):
            res = self.pipeline.depth(x)
        depth = torch.where(self.pipeline.written_pixels(res), res.depth, torch.full_like(res.depth, float("nan")))
        return {**batch, "depth": depth[:, 0].numpy().astype(np.float32),
                "confidence": res.confidence[:, 0].numpy().astype(np.float32)}
