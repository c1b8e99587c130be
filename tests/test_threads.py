import threading

import pytest
import torch

from prismstereo import OptionError, ShapeError
from prismstereo.threads import per_image, torch_threads


@pytest.fixture
def two_threads():
    from prismstereo.threads import set_torch_threads

    threads = torch.get_num_threads()
    set_torch_threads(2)
    yield
    set_torch_threads(threads)


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


def test_torch_threads_scopes_nest_overlap_and_restore_the_first_count(two_threads):
    """Nested scopes restore the enclosing one's count; a batch's workers inside a scope leave it alone; a thread
    that opens a scope while another thread holds one thread returns to the count from before the first scope (not
    to the one thread it would read as its own); errors restore too."""
    with torch_threads(1):
        with torch_threads(1):
            assert torch.get_num_threads() == 1
        assert torch.get_num_threads() == 1
        per_image(lambda x: x, torch.zeros(2, 1, 2, 2))  # a batch's workers open scopes of their own
        assert torch.get_num_threads() == 1  # the outer scope is still open here
        seen = []

        def late():  # started while the scope holds one thread: it starts with one, and returns to two
            with torch_threads(1):
                seen.append(torch.get_num_threads())
            seen.append(torch.get_num_threads())

        other = threading.Thread(target=late)
        other.start()
        other.join()
        assert seen == [1, 2]
    assert torch.get_num_threads() == 2
    opened, release = threading.Event(), threading.Event()

    def hold():
        with torch_threads(1):
            opened.set()
            release.wait(5)

    other = threading.Thread(target=hold)
    other.start()
    opened.wait(5)
    with pytest.raises(RuntimeError, match="boom"), torch_threads(1):
        raise RuntimeError("boom")
    assert torch.get_num_threads() == 2  # this thread's scopes are closed, whatever the other thread holds
    release.set()
    other.join()
    assert torch.get_num_threads() == 2
    with pytest.raises(OptionError, match="count must be an int >= 1"):
        with torch_threads(0):
            pass


def test_thread_plan_is_the_one_decision_of_every_count():
    """A process's share of the cores, its model and per-frame graph on all of them, the temporal graph and the side
    work on one, decoding on the rest; shares of the machine among worker processes."""
    import os

    from prismstereo.threads import ThreadPlan, thread_plan

    assert thread_plan(cores=8) == ThreadPlan(cores=8, torch=8, graph=8, temporal_graph=1, decode=7, side=1)
    assert thread_plan(3, cores=8).cores == 2 and thread_plan(4, cores=2).cores == 1  # at least one each
    assert thread_plan(cores=1).decode == 1
    assert thread_plan().cores == (os.cpu_count() or 1)
    for bad in (0, 1.5, True):
        with pytest.raises(OptionError, match="workers must be an int >= 1"):
            thread_plan(bad)
    with pytest.raises(OptionError, match="cores must be an int >= 1"):
        thread_plan(cores=0)


def test_set_torch_threads_sets_the_programs_count_and_what_scopes_return_to():
    from prismstereo.threads import set_torch_threads

    before = torch.get_num_threads()
    try:
        set_torch_threads(1)
        assert torch.get_num_threads() == 1
        with torch_threads(2):
            set_torch_threads(3)  # inside a scope: the scope keeps its count, and returns to the program's
            assert torch.get_num_threads() == 2
        assert torch.get_num_threads() == 3
    finally:
        set_torch_threads(before)
    with pytest.raises(OptionError, match="count must be an int >= 1"):
        set_torch_threads(0)
