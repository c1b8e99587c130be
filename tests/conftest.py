"""Shared fixtures: dtypes with their tolerances, and the rigs used across tests."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch
from filelock import FileLock

from prismstereo import BiPrismRig, thesis_setup1, thesis_setup2
from prismstereo.threads import set_torch_threads, torch_threads

# Round-trip tolerances of project_points (issue: < 1e-6 px in float64, < 1e-3 px in float32).
ROUND_TRIP_TOL = {torch.float64: 1e-6, torch.float32: 1e-3}


@pytest.fixture(params=[torch.float32, torch.float64], ids=["f32", "f64"])
def dtype(request) -> torch.dtype:
    return request.param


def offset_rig() -> BiPrismRig:
    """Setup 1 with the prism translated 3 mm along x (thesis sec. 5.5)."""
    return thesis_setup1().replace(prism_offset_x_mm=3.0)


def tilted_rig() -> BiPrismRig:
    """Setup 1 with a misaligned prism: offset, and tilted about all three axes."""
    return thesis_setup1().replace(prism_offset_x_mm=-1.5, prism_tilt_deg=(1.0, -2.0, 0.5))


RIGS = {
    "setup1": thesis_setup1,
    "setup2": thesis_setup2,
    "offset": offset_rig,
    "tilted": tilted_rig,
}


@pytest.fixture(params=sorted(RIGS), ids=sorted(RIGS))
def rig(request) -> BiPrismRig:
    return RIGS[request.param]()


def scaled_rig(rig: BiPrismRig | None = None, scale: int = 8) -> BiPrismRig:
    """The rig's field of view on a sensor ``scale`` times coarser (fast tests, same geometry)."""
    return (rig or thesis_setup1()).downscaled(scale)


def random_pixels(rig: BiPrismRig, n: int, dtype: torch.dtype, seed: int = 0) -> torch.Tensor:
    """(n, 2) uniformly random pixel coordinates on the sensor (seeded)."""
    gen = torch.Generator().manual_seed(seed)
    scale = torch.tensor([rig.image_width - 1.0, rig.image_height - 1.0], dtype=dtype)
    return torch.rand(n, 2, generator=gen, dtype=dtype) * scale


@pytest.fixture(scope="module")
def one_thread():
    """Small tensors: intra-op threads only add contention on a shared CPU (use per module with
    ``pytestmark = pytest.mark.usefixtures("one_thread")``)."""
    with torch_threads(1):
        yield


def _xdist_worker() -> bool:
    return "PYTEST_XDIST_WORKER" in os.environ


# Tests sharing an expensive module or session fixture (built once per worker process): under pytest-xdist each
# group runs on one worker, so the fixture is built once. Keys: a module's path, or a test's module::name.
# (pytest-xdist's own xdist_group marks are ignored with pytest 9.2: xdist 3.8 writes item._nodeid, which
# pytest 9 no longer reads, so the groups are declared here for the scheduler below.)
XDIST_GROUPS = {
    "tests/analysis/test_pinhole_rectify.py": "rectified cameras (setup1)",
    "tests/baselines/test_targets.py": "board_views",
    "tests/baselines/test_tsai.py": "board_views",
    "tests/baselines/test_zhang.py": "board_views",
    **{f"tests/calibration/test_fit.py::{name}": "calibrated" for name in (
        "test_result_report_and_plot", "test_outlier_view_is_flagged_and_weighted_down",
        "test_initial_poses_triangulate_the_boards", "test_diverged_fit_is_an_error",
        "test_board_jacobian_matches_finite_differences")},
    "tests/classical/test_temporal.py": "temporal model and sequences",
    "tests/export/test_graph.py": "exported graph and captures",
    "tests/learned/test_hybrid.py": "hybrid model",
    "tests/learned/test_exact_stage.py": "exact stage (its plane)",
    "tests/cli/test_calibrate.py": "calibration bench",
    "tests/calibration/test_joint.py": "joint calibration (its inputs and one solve)",
    "tests/jobs/test_jobs.py::test_ray_writes_the_same_files_and_survives_a_dead_worker": "local ray",
    "tests/classical/test_dense.py": "weak-texture models (weak)",
    "tests/classical/test_config.py": "the presets' models (_preset_model)",
    # one notebook kernel (its start and the imports of the first notebook are paid once, not once per worker)
    "tests/test_notebooks.py": "notebook kernel",
    # the captures of reference_cases (rendered once per process: the 1024 x 768 one in ~5 s, three 512 x 384 ones
    # in ~1 s each; each worker rendered those of its cases)
    "tests/test_reference_outputs.py": "reference captures",
}


def pytest_xdist_make_scheduler(config, log):
    """``-n N`` (pyproject's addopts): tests are handed out one by one to whichever worker is free, except the
    groups of :data:`XDIST_GROUPS`, each handed out whole. Another ``--dist`` mode keeps pytest-xdist's own."""
    if config.getvalue("dist") != "load":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class SharedFixtureScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            group = _group(nodeid)
            return f"group: {group}" if group else nodeid

    return SharedFixtureScheduling(config, log)


def _group(nodeid: str) -> str | None:
    module, _, test = nodeid.partition("::")
    return XDIST_GROUPS.get(module) or XDIST_GROUPS.get(f"{module}::{test.split('[')[0]}")


# The groups handed out first, longest first (~65 s and ~30 s of a worker on a quiet 2-core AMD EPYC); the other
# groups (5-15 s each) follow them, then the single tests.
FIRST = ("notebook kernel", "reference captures")


def pytest_collection_modifyitems(config, items):
    """Under pytest-xdist the longest units of work are handed out first (the groups of :data:`FIRST`, then the
    other groups of :data:`XDIST_GROUPS`, in collection order): the tail of the run is then many short tests, not
    one worker finishing the notebooks while the other idles. The order within each group stays the collection
    order."""
    if _xdist_worker():  # (collection runs on the workers, where xdist sets numprocesses to None)
        def rank(item) -> int:
            group = _group(item.nodeid)
            return FIRST.index(group) if group in FIRST else len(FIRST) + (group is None)

        items.sort(key=rank)


@pytest.fixture(scope="session", autouse=True)
def one_thread_per_worker():
    """Under pytest-xdist (``-n 2`` in pyproject's addopts) each worker process runs torch on one intra-op
    thread, and so do the processes it starts (notebook kernels): two workers of two threads each on a 2-core
    machine only contend. Tests that need more threads set them themselves (``two_threads``). Without xdist
    nothing changes."""
    if not _xdist_worker():
        yield
        return
    threads = torch.get_num_threads()
    set_torch_threads(1)  # the worker process's own count (scopes of the tests return to it)
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("OMP_NUM_THREADS", "1")
        yield
    set_torch_threads(threads)


@pytest.fixture(scope="session", autouse=True)
def onnx_cache(tmp_path_factory) -> Path:
    """The cache of exported graphs (:func:`~prismstereo.export.cached_graphs`, ``$PRISMSTEREO_CACHE``) in a
    directory of this session: no test reads or writes the user's ``~/.cache/prismstereo``, so a run here exports what
    one on a clean CI machine does, and tests of the same graph export it once (see ``export_once``). Under pytest-xdist
    the workers share one directory of this run (the parent of their base temp dirs): a graph one worker exported,
    another loads; both write a graph to a temporary name and rename it, so none reads half a file."""
    if _xdist_worker():
        root = tmp_path_factory.getbasetemp().parent / "prismstereo_cache"
        root.mkdir(exist_ok=True)
    else:
        root = tmp_path_factory.mktemp("prismstereo_cache")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("PRISMSTEREO_CACHE", str(root))
        yield root


@pytest.fixture(scope="session")
def export_once(onnx_cache):
    """``export_once(model)``: the path of ``model``'s ONNX graph (1 channel, default opset), exported once per
    session for each rig, range and options, under the name and in the directory where
    :func:`~prismstereo.export.cached_graphs` looks for it (:func:`~prismstereo.export.cache_path`, the key of the
    model): tests that check the same graph, and the CLI's ``--backend onnx``, share one export;
    ``export_once(model, temporal=options)``: the graph of the model's temporal band, where
    :func:`~prismstereo.export.cached_graphs` keeps it (an ONNX predictor of the session's cache shares it too). A
    file lock per graph makes a second xdist worker wait for the first one's export instead of exporting it again;
    the graph appears under its name only once complete (atomic rename, as in ``export_cached``)."""
    from prismstereo.export import cache_path, export_cached

    def export(model, temporal=None) -> Path:
        path = cache_path(model, temporal=temporal, cache_dir=onnx_cache / "onnx")
        if not path.is_file():
            path.parent.mkdir(parents=True, exist_ok=True)
            with FileLock(path.with_suffix(".lock")):
                export_cached(model.eval(), path, temporal=None if temporal is None else model.tracker(temporal))
        return path

    return export
