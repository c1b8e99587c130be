"""Quiet C libraries: :func:`c_stderr_silenced` discards what native code writes straight to the process's stderr
(libpng's "Read Error" on a truncated file, Ray's connection retries), where the Python error it raises says the same
in one line."""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from collections.abc import Iterator

__all__ = ["c_stderr_silenced"]


@contextlib.contextmanager
def c_stderr_silenced() -> Iterator[None]:
    """Within the block, file descriptor 2 goes to a discarded temporary file. Process-wide: used where nothing
    else writes there (before a progress bar starts).

    Example:
        >>> with c_stderr_silenced():
        ...     _ = os.write(2, b"not shown")
    """
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no file descriptor 2 (an embedding host): nothing to silence
        yield
        return
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
