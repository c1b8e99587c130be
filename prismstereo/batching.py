"""A batch in torch eager, image by image on worker threads.

:meth:`~prismstereo.model.PrismStereo.forward` evaluates an eager batch with :func:`per_image`: ``torch.
get_num_threads()`` images at a time on worker threads, each with its share of the caller's intra-op threads
(one each with the default 2) and the caller's grad / inference mode (both are thread-local in torch); the
caller's thread count is restored afterwards (``torch.set_num_threads`` also sets torch's process-wide
default). A traced or exported model is one graph for the whole batch instead.

Why threads of one intra-op thread each (1024 x 768, 2 cores): one image with 2 threads spends part of its time
in kernels that do not scale (OpenMP threads spin or wait), two images with 2 threads each oversubscribe the
cores (A/B in one process: 254 ms per image at batch 8 against 222 ms with one thread per worker; batch 1
254 ms). A batch of 8 as one tensor was slower (0.91x batch 1: the coarse level alone 107 -> 193 ms per image,
0.9 M minor page faults per call, every volume of 8 images a fresh mmap). ``benchmarks/onnx_speed.py``, nine
runs with ``downsample=1``: batch 8 gave 1.04-1.28x the images/s of batch 1 (~185-240 ms per image at batch 1);
the pyramid 1.07x in one run. Sub-batches of 2 or 4 images per worker gave 104 / 116 against 108 ms per image
(pyramid, batch 8). The ceiling is the machine: two images at once on one thread each cost 281 ms of CPU per
image against 217 ms for one image alone (the pyramid; the two cores slow each other down), while a second
intra-op thread already makes one image 1.38x faster; earlier, slower graphs gave 1.16x / 1.24x for batch 8, and
with faster single images (~93-103 ms) 1.13x / 1.20x. With the pyramid at 1024 x 768 one image takes 95 ms on
one thread and 57 ms on two (1.67x), so two images at once could give at most 1.2x batch 1's images/s; they took
108-115 ms each, as two threads and as two processes alike (the two cores share the L3 cache and memory
bandwidth: a streaming kernel gets 147 GB/s per core from L2-sized arrays, 106 + 91 GB/s with 16 MB ones and
33 + 33 GB/s from DRAM against 51.5 alone); batch 8 gave 1.07x / 1.22x.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import torch

from prismstereo.errors import check_shape

__all__ = ["per_image"]

T = TypeVar("T")


def per_image(fn: Callable[[torch.Tensor], T], images: torch.Tensor) -> list[T]:
    """``fn`` of every image of a batch, in order, ``torch.get_num_threads()`` at a time on worker threads.

    Args:
        fn: called with one image (1, C, H, W) at a time.
        images: (B, C, H, W).

    Returns:
        [fn(images[0:1]), ..., fn(images[B - 1:B])].

    Raises:
        ShapeError: ``images`` is not (B, C, H, W). Whatever ``fn`` raises (the caller's thread count is restored
        first).

    Example:
        >>> [float(t) for t in per_image(lambda x: x.sum(), torch.arange(3.0).view(3, 1, 1, 1))]
        [0.0, 1.0, 2.0]
    """
    check_shape(images, ["B", "C", "H", "W"], "images")
    b = images.shape[0]
    grad, inference = torch.is_grad_enabled(), torch.is_inference_mode_enabled()
    threads = torch.get_num_threads()
    workers = min(b, threads)

    def one(i: int) -> T:  # grad and inference mode are thread-local: carry the caller's
        if workers > 1:  # the caller's threads split between the images in flight
            torch.set_num_threads(threads // workers)
        with torch.inference_mode(inference), torch.set_grad_enabled(grad):
            return fn(images[i:i + 1])

    if workers == 1:
        return [one(i) for i in range(b)]
    try:
        with ThreadPoolExecutor(workers) as pool:
            return list(pool.map(one, range(b)))
    finally:  # the workers' setting also reached torch's process-wide default: restore it
        torch.set_num_threads(threads)
