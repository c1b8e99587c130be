"""Every docstring example of the package runs and prints what it shows.

Examples use ``torch``, ``Path``, ``thesis_setup1`` and ``thesis_setup2`` without importing them (provided
here). ``python -m prismstereo.cli`` (``prismstereo.cli.__main__``) is left out: importing it runs the command.
"""

import doctest
import importlib
import inspect
import pkgutil
from pathlib import Path

import pytest
import torch

import prismstereo
from prismstereo import thesis_setup1, thesis_setup2
from prismstereo.threads import torch_threads

SKIP = {"prismstereo.cli.__main__"}
MODULES = sorted(m.name for m in pkgutil.walk_packages(prismstereo.__path__, "prismstereo.") if m.name not in SKIP)


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    module = importlib.import_module(name)
    globs = {"torch": torch, "Path": Path, "thesis_setup1": thesis_setup1, "thesis_setup2": thesis_setup2}
    with torch_threads(1):
        result = doctest.testmod(module, extraglobs=globs, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
                                 report=True, verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {name}"


def test_public_functions_have_examples():
    """Public functions of the library modules carry an example (the house style; CLI modules excluded)."""
    missing = []
    for name in MODULES:
        if "._" in name or name.startswith("prismstereo.cli"):
            continue
        module = importlib.import_module(name)
        for attr in getattr(module, "__all__", []):
            obj = getattr(module, attr)
            if inspect.isfunction(obj) and obj.__module__ == name and ">>>" not in (obj.__doc__ or ""):
                missing.append(f"{name}.{attr}")
    assert not missing, f"no example in: {', '.join(missing)}"
