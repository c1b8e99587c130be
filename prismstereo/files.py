"""Whole files only: every file the package writes goes under a temporary name beside its place and is renamed
into it when complete (:func:`replacing`), so a reader, or a job stopped half-way, sees the old file or the whole
new one; :func:`partial_stem` finds the temporary files a killed process left. No torch.
"""

from __future__ import annotations

import contextlib
import os
import re
from collections.abc import Iterator
from pathlib import Path

__all__ = ["partial_stem", "replacing"]


@contextlib.contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """A temporary name beside ``path`` (same suffix, so that writers choosing a format by suffix still do) that is
    renamed to ``path`` when the block ends without an exception, and removed when it raises: a reader, or a job
    stopped half-way, sees the old file or the whole new one, never part of one (``os.replace`` is atomic within a
    file system). Creates the parent directory.

    Example:
        >>> with replacing("out/depth.npy") as partial:  # doctest: +SKIP
        ...     np.save(partial, np.zeros((2, 2)))
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.stem}.{os.getpid()}.partial{path.suffix}")  # partial_stem reads it back
    try:
        yield partial
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)


def partial_stem(path: str | Path) -> str | None:
    """The stem of the file a temporary file of :func:`replacing` was to become, None for any other name (a
    process killed inside ``replacing`` leaves its temporary file; a job's clean-up finds them by this).

    Example:
        >>> partial_stem(".depth_000003.4711.partial.npy"), partial_stem("depth_000003.npy")
        ('depth_000003', None)
    """
    found = re.fullmatch(r"\.(.+)\.\d+\.partial(\.[^.]*)?", Path(path).name)
    return None if found is None else found.group(1)
