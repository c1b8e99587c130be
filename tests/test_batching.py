import threading

import pytest
import torch

from prismstereo import ShapeError
from prismstereo.batching import per_image


@pytest.fixture
def two_threads():
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(threads)


def test_images_in_order_on_workers_with_the_callers_modes(two_threads):
    """Every image once, results in batch order; two workers of one intra-op thread each (off the main
    thread), under the caller's grad / inference mode; the caller's thread count restored."""
    seen = []

    def fn(x):
        seen.append((threading.current_thread() is threading.main_thread(), torch.get_num_threads(),
                     torch.is_grad_enabled(), torch.is_inference_mode_enabled()))
        return x.sum()

    images = torch.arange(5.0).view(5, 1, 1, 1)
    with torch.no_grad():
        assert [float(t) for t in per_image(fn, images)] == [0.0, 1.0, 2.0, 3.0, 4.0]
    with torch.inference_mode():
        per_image(fn, images[:2])
    assert seen == [(False, 1, False, False)] * 5 + [(False, 1, False, True)] * 2
    assert torch.get_num_threads() == 2


def test_one_image_or_one_thread_runs_inline_and_errors_restore_threads(two_threads):
    assert per_image(lambda x: threading.current_thread() is threading.main_thread(), torch.zeros(1, 1, 2, 2)) == [
        True]

    def fail(x):
        raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        per_image(fail, torch.zeros(3, 1, 2, 2))
    assert torch.get_num_threads() == 2
    with pytest.raises(ShapeError, match="images"):
        per_image(lambda x: x, torch.zeros(3, 2, 2))
