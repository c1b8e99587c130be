"""prismstereo.lazy: a package's names imported on first use."""

import sys

import pytest

from prismstereo.lazy import lazy_names


def test_names_are_imported_when_asked_for():
    getattr_, dir_ = lazy_names("pkg", {"sqrt": "math", "dumps": "json"}, ["sqrt", "dumps"])
    assert getattr_("sqrt")(9.0) == 3.0 and dir_() == ["dumps", "sqrt"]
    with pytest.raises(AttributeError, match="module 'pkg' has no attribute 'cos'"):
        getattr_("cos")


def test_the_packages_resolve_every_name_they_list():
    """Every name in the lazy packages' __all__ resolves (a stale module name fails here, not in a user's code)."""
    import prismstereo
    import prismstereo.classical
    import prismstereo.export
    import prismstereo.jobs
    import prismstereo.stream

    for package in (prismstereo, prismstereo.classical, prismstereo.export, prismstereo.jobs, prismstereo.stream):
        assert sorted(dir(package)) == sorted(package.__all__)
        for name in package.__all__:
            assert getattr(package, name) is not None, f"{package.__name__}.{name}"
    assert "torch" in sys.modules  # resolving them imported the models
