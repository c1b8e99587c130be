"""Thread counts, owned in one place: what every part of a process gets (:func:`thread_plan`), torch's intra-op
count (scoped settings, :func:`torch_threads`; a program's own, :func:`set_torch_threads`) and a batch evaluated
image by image (:func:`per_image`). No other module sets a thread count.

``torch.set_num_threads`` sets the count of the calling thread and the default of threads that start later, so two
pieces of code on different threads that each set it and restore "their" previous value can restore a count the
other one set (a thread started while another holds one thread reads that as its own). Every setting of the package
goes through :func:`torch_threads`: a scope sets the count of its thread, and when it closes its thread returns to
the enclosing scope's count, or to the count from before the first open scope of any thread (one lock guards that
bookkeeping), which threads started later inherit again. Two users of it:

* :func:`per_image`: a batch in torch eager, ``torch.get_num_threads()`` images at a time on worker threads, each
  with its share of the caller's threads and the caller's grad / inference mode (both are thread-local in torch):
  on a few cores one image does not keep every thread busy (parts of the chain do not scale), while images in
  flight on one thread each do; :meth:`~prismstereo.classical.model.PrismStereo.forward` uses it (a traced or exported
  model is one graph for the whole batch instead);
* :class:`~prismstereo.stream.DepthStream`: an ONNX stream does its own tensor work on one torch thread, so that
  torch's OpenMP workers do not compete with onnxruntime's threads for the same cores between the graph's runs.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, NamedTuple, TypeVar

from prismstereo.errors import check_int, check_shape

if TYPE_CHECKING:  # imported where tensors are: a process that only runs exported graphs never imports torch
    import torch

__all__ = ["ThreadPlan", "per_image", "set_torch_threads", "thread_plan", "torch_threads"]

T = TypeVar("T")

_LOCK = threading.Lock()
_state = {"open": 0, "saved": 1}  # open torch_threads scopes (any thread), the count before the first of them
_scopes = threading.local()  # each thread's open scopes' counts, innermost last


@contextlib.contextmanager
def torch_threads(count: int) -> Iterator[None]:
    """Run the block with ``count`` torch intra-op threads, then restore the count.

    Scopes may nest, and overlap across threads: each sets its thread's count when it opens; when it closes, the
    thread returns to the enclosing scope's count, or to the count from before the first scope that any thread
    opened (threads started later start from it too). In a process that has not imported torch there are no
    torch threads to set: the scope is empty.

    Args:
        count: threads (>= 1).

    Raises:
        OptionError: ``count`` is not an int >= 1.

    Example:
        >>> before = torch.get_num_threads()
        >>> with torch_threads(1):
        ...     inside = torch.get_num_threads()
        >>> inside, torch.get_num_threads() == before
        (1, True)
    """
    check_int(count, "count", 1)
    torch = sys.modules.get("torch")
    if torch is None:  # no torch work can run in the block
        yield
        return
    stack = _scopes.__dict__.setdefault("counts", [])
    with _LOCK:
        if _state["open"] == 0:
            _state["saved"] = torch.get_num_threads()
        _state["open"] += 1
        stack.append(count)
        torch.set_num_threads(count)
    try:
        yield
    finally:
        with _LOCK:
            _state["open"] -= 1
            stack.pop()
            torch.set_num_threads(stack[-1] if stack else _state["saved"])


def per_image(fn: Callable[[torch.Tensor], T], images: torch.Tensor) -> list[T]:
    """``fn`` of every image of a batch, in order, ``torch.get_num_threads()`` at a time on worker threads, each
    with an equal share of the caller's threads (:func:`torch_threads`).

    Args:
        fn: called with one image (1, C, H, W) at a time.
        images: (B, C, H, W).

    Returns:
        [fn(images[0:1]), ..., fn(images[B - 1:B])].

    Raises:
        ShapeError: ``images`` is not (B, C, H, W). Whatever ``fn`` raises (the thread count is restored first).

    Example:
        >>> [float(t) for t in per_image(lambda x: x.sum(), torch.arange(3.0).view(3, 1, 1, 1))]
        [0.0, 1.0, 2.0]
    """
    import torch

    check_shape(images, ["B", "C", "H", "W"], "images")
    b = images.shape[0]
    grad, inference = torch.is_grad_enabled(), torch.is_inference_mode_enabled()
    threads = torch.get_num_threads()
    workers = min(b, threads)

    def one(i: int) -> T:  # grad and inference mode are thread-local: carry the caller's
        with torch.inference_mode(inference), torch.set_grad_enabled(grad):
            return fn(images[i:i + 1])

    if workers == 1:
        return [one(i) for i in range(b)]

    def share(i: int) -> T:  # the caller's threads split between the images in flight
        with torch_threads(threads // workers):
            return one(i)

    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(share, range(b)))


def set_torch_threads(count: int) -> None:
    """Set torch's intra-op thread count of the calling program (a script's or a test session's start): the count
    the calling thread runs with (unless it is inside a :func:`torch_threads` scope, which keeps its own until it
    closes), threads started later start with, and the outermost open scopes return to.

    Args:
        count: threads (>= 1).

    Raises:
        OptionError: ``count`` is not an int >= 1.

    Example:
        >>> before = torch.get_num_threads(); set_torch_threads(1)
        >>> torch.get_num_threads(); set_torch_threads(before)
        1
    """
    import torch

    check_int(count, "count", 1)
    with _LOCK:
        stack = _scopes.__dict__.setdefault("counts", [])
        if _state["open"]:
            _state["saved"] = count
        if not stack:
            torch.set_num_threads(count)


class ThreadPlan(NamedTuple):
    """The threads of one process's parts (:func:`thread_plan`).

    Attributes:
        cores: the cores the process has (its share of the machine's among the worker processes).
        torch: torch intra-op threads of the model in torch.
        graph: onnxruntime intra-op threads of a per-frame graph.
        temporal_graph: onnxruntime intra-op threads of a temporal graph (the band between key frames).
        decode: video decoding threads (FFmpeg's), beside the graph.
        side: torch threads of the tensor work beside the model (reading, writing, an ONNX stream's own work).
    """

    cores: int
    torch: int
    graph: int
    temporal_graph: int
    decode: int
    side: int


def thread_plan(workers: int = 1, *, cores: int | None = None) -> ThreadPlan:
    """The one decision of every thread count: what each part of a process gets when ``workers`` processes share
    ``cores`` (default: the machine's, ``os.cpu_count()``).

    Each process has ``cores // workers`` (at least 1). Its model runs on all of them, in torch or as the per-frame
    graph. A temporal graph gets one: the band's graph is hundreds of small operations on the binned frame that a
    second thread does not speed up, while waking it for each costs CPU time that a video's decoding and the writing
    need on the other core (``docs/design.md``, implementation choices). Decoding gets every core but the graph's;
    the tensor work beside the model gets one thread, so that torch's OpenMP workers do not compete with the
    model's threads (or onnxruntime's spinning ones) for the same cores.

    Args:
        workers: processes sharing the cores (>= 1).
        cores: the cores to share; None: ``os.cpu_count()``.

    Returns:
        ThreadPlan.

    Raises:
        OptionError: ``workers`` or ``cores`` not an int >= 1.

    Example:
        >>> thread_plan(cores=2)
        ThreadPlan(cores=2, torch=2, graph=2, temporal_graph=1, decode=1, side=1)
        >>> thread_plan(2, cores=2).graph
        1
    """
    check_int(workers, "workers", 1)
    check_int(cores, "cores", 1, none=True)
    own = max(1, (cores or os.cpu_count() or 1) // workers)
    return ThreadPlan(cores=own, torch=own, graph=own, temporal_graph=1, decode=max(1, own - 1), side=1)
