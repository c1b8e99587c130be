"""Names a package imports on first use (PEP 562), so that importing it stays light: ``import prismstereo`` and the
packages a deployed graph needs (:mod:`prismstereo.export`, :mod:`prismstereo.jobs`, :mod:`prismstereo.stream`,
:mod:`prismstereo.classical`) import no torch until a name that needs it is asked for.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["lazy_names"]


def lazy_names(package: str, modules: Mapping[str, str],
               names: list[str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """A package's module-level ``__getattr__`` and ``__dir__``: each name of ``modules`` imported from its module
    (a full module name) when first asked for.

    Args:
        package: the package's name, for the error of an unknown name.
        modules: name -> the module that defines it.
        names: the package's ``__all__`` (what ``dir()`` lists).

    Example:
        >>> getattr_, dir_ = lazy_names("pkg", {"sqrt": "math"}, ["sqrt"])
        >>> getattr_("sqrt")(4.0), dir_()
        (2.0, ['sqrt'])
    """

    def __getattr__(name: str) -> Any:
        if name in modules:
            return getattr(importlib.import_module(modules[name]), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted(names)

    return __getattr__, __dir__
