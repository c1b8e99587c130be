"""Exceptions of prismstereo and the checks that raise them at public entry points.

Every error a user can trigger through bad input derives from :class:`PrismStereoError` (and from
``ValueError`` or ``TypeError`` where that is the natural base), so callers can catch the whole family
with one ``except PrismStereoError``. Library code never uses ``assert`` on user input.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import torch


__all__ = [
    "PrismStereoError",
    "RigError",
    "ShapeError",
    "ImageValueError",
    "OptionError",
    "ExportError",
    "CalibrationError",
    "check_shape",
    "check_option",
    "check_int",
    "check_number",
    "check_odd",
    "check_floating",
]


class PrismStereoError(Exception):
    """Base class of every error raised by prismstereo on bad input."""


class RigError(PrismStereoError, ValueError):
    """An invalid rig: bad field values, a malformed rig file, or a geometry that cannot image."""


class ShapeError(PrismStereoError, ValueError):
    """A tensor argument has the wrong shape."""


class ImageValueError(PrismStereoError, ValueError):
    """A capture's values are outside [0, 1] (e.g. 8-bit levels passed as floats)."""


class OptionError(PrismStereoError, ValueError):
    """An option string (a ``Literal[...]`` argument) is not one of the valid choices."""


class ExportError(PrismStereoError, ValueError):
    """An ONNX model cannot be exported, loaded or run (re-exported by :mod:`prismstereo.export`)."""


class CalibrationError(PrismStereoError, ValueError):
    """A calibration that cannot be run or did not succeed: bad target, too few views, a diverged fit."""


def check_shape(x: Any, shape: Sequence[str | int], name: str = "tensor") -> None:
    """Check that ``x`` is a tensor whose trailing dims match ``shape``.

    ``shape`` is a list of dims, Kornia style: ``"*"`` (only first) stands for any number of leading dims,
    an ``int`` must match exactly and any other string (``"B"``, ``"N"``) matches any size.

    Args:
        x: the argument to check.
        shape: e.g. ``["*", 2]`` or ``["B", "C", "H", "W"]``.
        name: the argument's name, used in the message.

    Raises:
        ShapeError: if ``x`` is not a tensor or its shape does not match.

    Example:
        >>> check_shape(torch.zeros(4, 5, 2), ["*", 2], "uv")
    """
    import torch  # here, not at the top: the package imports without torch (a deployed graph needs none)

    if not isinstance(x, torch.Tensor):
        raise ShapeError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    dims = list(shape)
    wildcard = bool(dims) and dims[0] == "*"
    fixed = dims[1:] if wildcard else dims
    ok = x.dim() >= len(fixed) if wildcard else x.dim() == len(fixed)
    if ok:
        for want, got in zip(fixed, x.shape[x.dim() - len(fixed):], strict=True):
            if isinstance(want, int) and want != got:
                ok = False
                break
    if not ok:
        expected = "(" + ", ".join(str(d) for d in dims) + ")"
        raise ShapeError(f"{name} must have shape {expected}, got {tuple(x.shape)}")


def check_option(value: Any, choices: Iterable[str], name: str) -> str:
    """Return ``value`` if it is one of ``choices``, else raise an :class:`OptionError` listing them.

    Example:
        >>> check_option("left", ("left", "right"), "half")
        'left'
    """
    choices = tuple(choices)
    if value not in choices:
        raise OptionError(f"Unknown {name} {value!r}. Choose from: {', '.join(map(repr, choices))}")
    return value


def check_int(value: Any, name: str, least: int, *, none: bool = False, most: int | None = None) -> Any:
    """Return ``value`` if it is an int >= ``least`` (and <= ``most`` when given; not a bool; or None with ``none``),
    else raise an :class:`OptionError` saying so.

    Example:
        >>> check_int(3, "band", 1)
        3
        >>> check_int(9, "window", 1, most=8)
        Traceback (most recent call last):
        ...
        prismstereo.errors.OptionError: window must be an int in [1, 8], got 9
    """
    if value is None and none:
        return value
    if isinstance(value, bool) or not isinstance(value, int) or value < least or (most is not None and value > most):
        bound = f">= {least}" if most is None else f"in [{least}, {most}]"
        raise OptionError(f"{name} must be an int {bound}{' or None' if none else ''}, got {value!r}")
    return value


def check_odd(value: Any, name: str, least: int = 1, *, zero: bool = False) -> Any:
    """Return ``value`` if it is an odd int >= ``least`` (not a bool; or 0 with ``zero``, an "off" value), else
    raise an :class:`OptionError` saying so: the check of every window size.

    Example:
        >>> check_odd(5, "window")
        5
    """
    ok = isinstance(value, int) and not isinstance(value, bool) and (
        (zero and value == 0) or (value >= least and value % 2 == 1))
    if not ok:
        what = f"an odd int >= {least}" if least > 1 else "a positive odd int"
        raise OptionError(f"{name} must be {'0 (off) or ' if zero else ''}{what}, got {value!r}")
    return value


def check_number(value: Any, name: str, low: float, high: float, what: str | None = None, *, none: bool = False,
                 open_low: bool = False, infinite: bool = False) -> Any:
    """Return ``value`` if it is a number (not a bool) in [low, high] ((low, high] with ``open_low``; or None with
    ``none``), else raise an :class:`OptionError` saying it must be ``what`` (default: the interval). With ``high``
    inf the value must be finite unless ``infinite`` (inf then means "off", e.g. a threshold never reached).

    Example:
        >>> check_number(0.5, "min_confidence", 0.0, 1.0)
        0.5
    """
    if value is None and none:
        return value
    finite_only = high == math.inf and not infinite
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and (
        low < value if open_low else low <= value) and (value < high if finite_only else value <= high)
    if not ok:
        what = what or f"a number in {'(' if open_low else '['}{low:g}, {high:g}]"
        raise OptionError(f"{name} must be {what}{' or None' if none else ''}, got {value!r}")
    return value


def check_floating(x: torch.Tensor, name: str = "tensor") -> None:
    """Raise a :class:`PrismStereoError` (``TypeError``) unless ``x`` is a floating-point tensor.

    Example:
        >>> check_floating(torch.zeros(3), "points")
    """
    import torch

    if not torch.is_floating_point(x):
        raise _DTypeError(f"{name} must be a floating-point tensor, got dtype {x.dtype}")


class _DTypeError(PrismStereoError, TypeError):
    """A tensor argument has a non-floating dtype."""
