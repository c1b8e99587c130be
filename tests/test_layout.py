"""The package's layout holds: no import cycles (modules, and packages along the data path), modules of at most 450
lines and functions of at most 80 unless a comment says why, one place that sets thread counts, and tests that
mirror the package."""

from __future__ import annotations

import ast
import collections
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "prismstereo"
MODULE_LINES, FUNCTION_LINES = 450, 80
# a function may be longer than FUNCTION_LINES where a comment right above it (or its decorators) says why
LONG_FUNCTION = re.compile(r"#\s*longer than 80 lines:")


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        name = ".".join(path.relative_to(ROOT).with_suffix("").parts)
        out[name.removesuffix(".__init__")] = path
    return out


def _imports(modules: dict[str, Path]) -> dict[str, set[str]]:
    """Each module's imports of the package's modules, wherever they are (module level, in functions, under
    TYPE_CHECKING): ``from a.b import c`` is an import of ``a.b``, and of ``a.b.c`` where that is a module."""
    edges: dict[str, set[str]] = collections.defaultdict(set)
    for name, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("prismstereo"):
                targets = [node.module, *(f"{node.module}.{a.name}" for a in node.names)]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names if a.name.startswith("prismstereo")]
            else:
                continue
            edges[name].update(t for t in targets if t in modules and t != name)
    return edges


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10_000))
    try:
        for v in sorted(graph):
            if v not in index:
                visit(v)
    finally:
        sys.setrecursionlimit(limit)
    return out


def _unit(module: str) -> str:
    """A module's package among the package's parts (``prismstereo.matching.band`` -> ``matching``; a top-level
    module is its own)."""
    return module.split(".")[1]


def test_no_import_cycles_between_modules_or_packages():
    """The root ``prismstereo`` is the facade (its names imported lazily) and is left out: modules import its
    ``__version__``. Every other import counts, in functions and under TYPE_CHECKING too."""
    modules = _modules()
    edges = {m: {t for t in ts if t != "prismstereo"} for m, ts in _imports(modules).items() if m != "prismstereo"}
    assert _cycles(edges) == []
    units: dict[str, set[str]] = collections.defaultdict(set)
    for module, targets in edges.items():
        units[_unit(module)].update(_unit(t) for t in targets if _unit(t) != _unit(module))
    assert _cycles(units) == []
    # the data path: the stages never import the models, the runtimes or the command line
    later = {"classical", "learned", "models", "predictor", "export", "stream", "jobs", "cli"}
    for stage in ("geometry", "epipolar", "matching", "depth"):
        assert not units[stage] & later, (stage, units[stage] & later)
    assert not units["classical"] & {"learned", "models", "predictor", "export", "stream", "jobs", "cli"}


def test_the_cycle_check_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def _long_functions(path: Path) -> list[str]:
    lines = path.read_text().splitlines()
    out = []
    for node in ast.walk(ast.parse("\n".join(lines))):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            length = node.end_lineno - node.lineno + 1
            first = min([node.lineno, *(d.lineno for d in node.decorator_list)])
            if length > FUNCTION_LINES and not LONG_FUNCTION.search(lines[first - 2] if first > 1 else ""):
                out.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({length} lines)")
    return out


def test_modules_and_functions_are_small():
    modules = _modules()
    long_modules = [f"{p.relative_to(ROOT)} ({n})" for p in modules.values()
                    if (n := len(p.read_text().splitlines())) > MODULE_LINES]
    assert long_modules == []
    assert [f for p in modules.values() for f in _long_functions(p)] == []


def test_the_function_length_check_reads_its_escape(tmp_path):
    body = "\n".join(["def f():"] + ["    x = 1"] * FUNCTION_LINES)
    (tmp_path / "a.py").write_text(body + "\n")
    (tmp_path / "b.py").write_text("# longer than 80 lines: one table\n" + body + "\n")
    global ROOT
    root, ROOT = ROOT, tmp_path
    try:
        assert _long_functions(tmp_path / "a.py") == ["a.py:1 f (81 lines)"]
        assert _long_functions(tmp_path / "b.py") == []
    finally:
        ROOT = root


def test_only_threads_sets_thread_counts():
    """Torch's thread counts (intra- and inter-op) are set in :mod:`prismstereo.threads` only: the package, its
    tests, benchmarks, notebooks and docs go through it (``torch_threads``, ``set_torch_threads``, ``thread_plan``)."""
    found = []
    for folder, suffixes in (("prismstereo", (".py",)), ("tests", (".py",)), ("benchmarks", (".py",)),
                             ("notebooks", (".ipynb",)), ("docs", (".py", ".md"))):
        for path in (ROOT / folder).rglob("*"):
            if path.suffix in suffixes and path != PACKAGE / "threads.py":
                if re.search(r"set_num_(interop_)?threads\s*\(", path.read_text()):
                    found.append(str(path.relative_to(ROOT)))
    assert found == []


@pytest.mark.parametrize("package", sorted(p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()))
def test_tests_mirror_the_package(package):
    """Each subpackage has its test folder, and each of its modules with public functions or classes a test module
    of its name, or its names in the folder's tests (a command of the CLI: its name, as the tests run it)."""
    folder = ROOT / "tests" / package
    assert folder.is_dir(), f"tests/{package} is missing"
    tests = "\n".join(p.read_text() for p in folder.glob("test_*.py"))
    untested = []
    for module in sorted((PACKAGE / package).glob("[!_]*.py")):
        tree = ast.parse(module.read_text())
        public = [n.name for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))
                  and not n.name.startswith("_")]
        names = [f'"{module.stem}"'] if package == "cli" else public  # a command: run by its name
        if public and not (folder / f"test_{module.stem}.py").is_file() and not any(
                re.search(rf"\b{re.escape(name)}\b" if name[0] != '"' else re.escape(name), tests) for name in names):
            untested.append(module.stem)
    assert untested == []


def test_top_level_modules_have_their_tests():
    """Each top-level module with public names has ``tests/test_<module>.py``, or its names in the top-level tests."""
    tests = "\n".join(p.read_text() for p in (ROOT / "tests").glob("test_*.py"))
    untested = []
    for module in sorted(PACKAGE.glob("[!_]*.py")):
        tree = ast.parse(module.read_text())
        public = [n.name for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))
                  and not n.name.startswith("_")]
        if public and not (ROOT / "tests" / f"test_{module.stem}.py").is_file() and not any(
                re.search(rf"\b{re.escape(name)}\b", tests) for name in public):
            untested.append(module.stem)
    assert untested == []


def test_importing_the_package_and_its_errors_needs_no_torch():
    """``import prismstereo`` (and the error family) stays light: every other name is imported on first use."""
    import subprocess
    import sys

    code = ("import sys; import prismstereo; from prismstereo import PrismStereoError, RigError; "
            "print('torch' in sys.modules, 'thesis_setup1' in dir(prismstereo), 'load_rig' in prismstereo._LAZY)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "True", "True"]


def test_every_xdist_group_names_an_existing_module_or_test():
    """A renamed test or module would silently leave its shared fixture's group (built once per worker instead of
    once): every key of conftest's XDIST_GROUPS names a test module, or a test function in one."""
    from tests.conftest import XDIST_GROUPS

    root = Path(__file__).resolve().parents[1]
    for key in XDIST_GROUPS:
        module, _, test = key.partition("::")
        path = root / module
        assert path.is_file(), key
        if test:
            assert f"def {test}(" in path.read_text(), key
