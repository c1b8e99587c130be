"""Every notebook in notebooks/ is executed (the figures they draw come from the library)."""

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

import prismstereo

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


def test_notebooks_exist():
    names = {p.name for p in NOTEBOOKS}
    for required in ("01_prism_geometry.ipynb", "02_synthetic_capture.ipynb", "03_epipolar.ipynb",
                     "04_depth.ipynb", "05_onnx_deployment.ipynb", "06_fov_and_error_analysis.ipynb",
                     "07_calibration.ipynb", "08_learned.ipynb"):
        assert required in names


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_executes(path, monkeypatch):
    # the notebooks' reduced runs: smaller sensors, fewer views, frames, timing runs and training steps (the same
    # calls on less data; a reader's run keeps the sizes its stored outputs show)
    monkeypatch.setenv("PRISMSTEREO_NOTEBOOK_QUICK", "1")
    nb = nbformat.read(path, as_version=4)
    # the kernel (it inherits this process' environment, PYTHONPATH included) imports the package under test, not
    # another installed copy
    package = str(Path(prismstereo.__file__).resolve().parent)
    nb.cells.insert(0, nbformat.v4.new_code_cell(
        f"import pathlib, prismstereo\nassert str(pathlib.Path(prismstereo.__file__).resolve().parent) == {package!r}"))
    # run from notebooks/ so relative paths (e.g. ../../shared/data) resolve as they do for a reader
    client = NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}})
    client.execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors
