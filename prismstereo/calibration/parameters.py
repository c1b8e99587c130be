"""The rig parameters a calibration can estimate, by name, and their vector form.

Every parameter is a field (or an entry of a field) of :class:`~prismstereo.geometry.rig.BiPrismRig`; the
names are the rig file's, with the tilt and distortion entries spelled out. A calibration works on a float64
vector of all of them in internal units (radians for angles) and frees a subset; :func:`rig_parameters` turns
that vector into the :class:`~prismstereo.geometry.parameters.RigParameters` the differentiable optics consume, and
:func:`vector_to_rig` writes it back to a rig file. The pixel size is never estimated: only f / pixel size
is observable in pixels, so the focal length is estimated with the pixel pitch held at its nominal value.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import NamedTuple

import torch

from prismstereo.errors import CalibrationError
from prismstereo.geometry.parameters import RigParameters
from prismstereo.geometry.rig import BiPrismRig

__all__ = ["NAMES", "ANGLES", "ParameterInfo", "INFO", "TOLERANCES", "rig_vector", "rig_parameters",
           "vector_to_rig", "tolerance_vector", "to_display", "check_names"]


class ParameterInfo(NamedTuple):
    """What a parameter is: its unit as reported and a short description."""

    unit: str
    description: str


INFO: dict[str, ParameterInfo] = {
    "focal_length_mm": ParameterInfo("mm", "focal length (at the nominal pixel size)"),
    "cx": ParameterInfo("px", "principal point column"),
    "cy": ParameterInfo("px", "principal point row"),
    "k1": ParameterInfo("", "radial distortion r^2"),
    "k2": ParameterInfo("", "radial distortion r^4"),
    "p1": ParameterInfo("", "tangential distortion p1"),
    "p2": ParameterInfo("", "tangential distortion p2"),
    "k3": ParameterInfo("", "radial distortion r^6"),
    "prism_offset_x_mm": ParameterInfo("mm", "prism x offset d"),
    "apex_distance_mm": ParameterInfo("mm", "apex distance T_o"),
    "prism_thickness_mm": ParameterInfo("mm", "prism thickness T"),
    "alpha_deg": ParameterInfo("deg", "prism angle alpha"),
    "refractive_index": ParameterInfo("", "glass index n"),
    "tilt_x_deg": ParameterInfo("deg", "prism tilt about x"),
    "tilt_y_deg": ParameterInfo("deg", "prism tilt about y"),
    "roll_deg": ParameterInfo("deg", "prism roll about z (apex line vs sensor columns)"),
}
NAMES: tuple[str, ...] = tuple(INFO)

# Default 1-sigma bench tolerances of a nominal rig (reported units; "%" entries relative to the nominal value,
# "%W" relative to the sensor width): what a user who built the rig from its parts' drawings knows. They are
# 2-5x the misalignments a careful assembly leaves (the calibration targets: f 1 %, principal point 5 px,
# k1 in [-0.1, 0.05], d 0.5 mm, T_o 2 mm, tilts 0.5 deg, roll 0.3 deg, alpha 0.1 deg, n 0.01).
TOLERANCES: dict[str, tuple[float, str]] = {
    "focal_length_mm": (2.0, "%"), "cx": (2.0, "%W"), "cy": (2.0, "%W"),
    "k1": (0.2, ""), "k2": (0.2, ""), "p1": (0.01, ""), "p2": (0.01, ""), "k3": (0.2, ""),
    "prism_offset_x_mm": (1.0, "mm"), "apex_distance_mm": (5.0, "mm"), "prism_thickness_mm": (0.5, "mm"),
    "alpha_deg": (0.3, "deg"), "refractive_index": (0.02, ""),
    "tilt_x_deg": (1.0, "deg"), "tilt_y_deg": (1.0, "deg"), "roll_deg": (1.0, "deg"),
}
ANGLES: frozenset[str] = frozenset({"alpha_deg", "tilt_x_deg", "tilt_y_deg", "roll_deg"})


def check_names(names: Iterable[str]) -> tuple[str, ...]:
    """Return ``names`` as a tuple, raising :class:`CalibrationError` (listing the valid names) on an unknown one.

    Example:
        >>> check_names(["k1", "roll_deg"])
        ('k1', 'roll_deg')
    """
    names = tuple(names)
    unknown = [n for n in names if n not in INFO]
    if unknown:
        raise CalibrationError(f"unknown rig parameter(s) {', '.join(unknown)}; valid: {', '.join(NAMES)}")
    return names


def rig_vector(rig: BiPrismRig) -> torch.Tensor:
    """(16,) float64 values of :data:`NAMES` in internal units (angles in radians).

    Example:
        >>> rig_vector(thesis_setup1())[NAMES.index("apex_distance_mm")]
        tensor(170., dtype=torch.float64)
    """
    tilt = [math.radians(a) for a in rig.prism_tilt_deg]
    values = [rig.focal_length_mm, rig.cx, rig.cy, *rig.distortion, rig.prism_offset_x_mm, rig.apex_distance_mm,
              rig.prism_thickness_mm, rig.alpha_rad, rig.refractive_index, *tilt]
    return torch.tensor(values, dtype=torch.float64)


def rig_parameters(vector: torch.Tensor, rig: BiPrismRig, distorted: bool = True) -> RigParameters:
    """The differentiable :class:`RigParameters` of a (16,) parameter vector (internal units); the pixel size and
    sensor size come from ``rig``. Gradients (and forward-mode tangents) flow from ``vector``.

    Args:
        vector: (16,) values of :data:`NAMES`.
        rig: the rig providing the pixel size and the sensor.
        distorted: False drops the distortion (pinhole formulas) when its entries are fixed at zero.

    Example:
        >>> p = rig_parameters(rig_vector(thesis_setup1()), thesis_setup1())
        >>> float(p.T_o), p.distortion.shape
        (170.0, torch.Size([5]))
    """
    v = vector
    return RigParameters(
        alpha=v[11], n=v[12], f=v[0], T=v[10], T_o=v[9],
        pixel_size=torch.tensor(rig.pixel_size_mm, dtype=v.dtype, device=v.device),
        cx=v[1], cy=v[2], d=v[8], tilt=v[13:16], distortion=v[3:8] if distorted else None,
        width=rig.image_width, height=rig.image_height,
    )


def vector_to_rig(vector: torch.Tensor, rig: BiPrismRig) -> BiPrismRig:
    """Write a (16,) parameter vector into a copy of ``rig`` (validated like any rig).

    Example:
        >>> v = rig_vector(thesis_setup1()); v[NAMES.index("k1")] = -0.05
        >>> vector_to_rig(v, thesis_setup1()).distortion[0]
        -0.05
    """
    x = [float(a) for a in vector.detach().cpu().tolist()]
    return rig.replace(
        focal_length_mm=x[0], principal_point=(x[1], x[2]), distortion=tuple(x[3:8]), prism_offset_x_mm=x[8],
        apex_distance_mm=x[9], prism_thickness_mm=x[10], alpha_deg=math.degrees(x[11]), refractive_index=x[12],
        prism_tilt_deg=tuple(math.degrees(a) for a in x[13:16]),
    )


def tolerance_vector(rig: BiPrismRig, overrides: dict[str, float] | None = None) -> torch.Tensor:
    """(16,) 1-sigma priors in internal units: :data:`TOLERANCES` resolved for ``rig``, with ``overrides``
    (reported units, absolute; ``inf`` removes a prior).

    Example:
        >>> float(tolerance_vector(thesis_setup1())[NAMES.index("cx")])
        20.48
    """
    overrides = dict(overrides or {})
    check_names(overrides)
    bad = {k: v for k, v in overrides.items() if not (isinstance(v, (int, float)) and float(v) > 0)}
    if bad:
        raise CalibrationError(f"tolerances must be positive numbers (inf for no prior), got {bad}")
    nominal = to_display(rig_vector(rig))
    out = []
    for i, name in enumerate(NAMES):
        value, unit = TOLERANCES[name]
        if name in overrides:
            value, unit = float(overrides[name]), ""
        elif unit == "%":
            value = abs(float(nominal[i])) * value / 100.0
        elif unit == "%W":
            value = rig.image_width * value / 100.0
        out.append(math.radians(value) if name in ANGLES else value)
    return torch.tensor(out, dtype=torch.float64)


def to_display(vector: torch.Tensor) -> torch.Tensor:
    """(*, 16) internal values (or standard errors) -> reported units (angles in degrees).

    Example:
        >>> to_display(rig_vector(thesis_setup1()))[NAMES.index("alpha_deg")]
        tensor(6.4000, dtype=torch.float64)
    """
    scale = torch.tensor([180.0 / math.pi if n in ANGLES else 1.0 for n in NAMES], dtype=vector.dtype,
                         device=vector.device)
    return vector * scale
