"""Every notebook in notebooks/ is executed (the figures they draw come from the library)."""

from pathlib import Path

import nbformat
import pytest
from jupyter_client.manager import KernelManager
from nbclient import NotebookClient

import prismstereo

FOLDER = Path(__file__).resolve().parents[1] / "notebooks"
NOTEBOOKS = sorted(FOLDER.glob("*.ipynb"))


def test_notebooks_exist():
    names = {p.name for p in NOTEBOOKS}
    for required in ("01_prism_geometry.ipynb", "02_synthetic_capture.ipynb", "03_epipolar.ipynb",
                     "04_depth.ipynb", "05_onnx_deployment.ipynb", "06_fov_and_error_analysis.ipynb",
                     "07_calibration.ipynb", "08_learned.ipynb"):
        assert required in names


@pytest.fixture(scope="module")
def kernel():
    """One kernel for all the notebooks (under pytest-xdist they run on one worker: tests/conftest.py's
    XDIST_GROUPS), each notebook after ``%reset -f`` (an empty namespace: a name a notebook uses without defining
    or importing it still fails), so that the imports and the library's first-call work are paid once, not once
    per notebook. The kernel runs from notebooks/, so relative paths (e.g. ../../shared/data) resolve as they do
    for a reader, and inherits this process' environment (PYTHONPATH included) with the notebooks' reduced runs:
    smaller sensors, fewer views, frames, timing runs and training steps, one of several like inputs (the same
    calls on less data; a reader's run keeps the sizes and inputs its stored outputs show)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("PRISMSTEREO_NOTEBOOK_QUICK", "1")
        manager = KernelManager(kernel_name="python3")
        manager.start_kernel(cwd=str(FOLDER))
    yield manager
    manager.shutdown_kernel(now=True)


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_executes(path, kernel):
    if not kernel.is_alive():  # a notebook before this one killed it
        kernel.restart_kernel(now=True)
    nb = nbformat.read(path, as_version=4)
    # an empty namespace and no figure left open; the kernel imports the package under test, not another copy
    package = str(Path(prismstereo.__file__).resolve().parent)
    nb.cells.insert(0, nbformat.v4.new_code_cell(
        "%reset -f\nimport matplotlib.pyplot, pathlib, prismstereo\nmatplotlib.pyplot.close('all')\n"
        f"assert str(pathlib.Path(prismstereo.__file__).resolve().parent) == {package!r}\n"
        "del matplotlib, pathlib, prismstereo"))
    client = NotebookClient(nb, km=kernel, timeout=600, kernel_name="python3",
                            resources={"metadata": {"path": str(FOLDER)}})
    client.execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors
