"""The rigs this package ships (the thesis' two setups) and :func:`load_rig`, which reads a rig file, JSON text,
a dict or one of them by name (the CLI's ``--rig``) and checks its geometry.

The presets are fixed rigs whose half-images both see through the prism (the tests check them with
:func:`~prismstereo.geometry.optics.check_rig_images`); building one does no ray tracing.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from prismstereo.geometry.optics import check_rig_images
from prismstereo.geometry.rig import BiPrismRig

__all__ = ["RIG_PRESETS", "load_rig", "thesis_setup1", "thesis_setup2"]


def thesis_setup1() -> BiPrismRig:
    """The thesis' main setup (Table 3.1): alpha 6.4 deg, n 1.48, f 25 mm, T 5.6 mm, T_o 170 mm.

    Sensor 1024 x 768 px of 4.65 um (4.7616 mm wide, the sensor width of thesis fig. 5.4). The back plane
    is 2 T / tan(alpha) = 99.85 mm wide, matching the thesis' 100 mm prism (b in eq. 5.16).

    Example:
        >>> round(thesis_setup1().prism_width_mm, 2)
        99.85
    """
    return BiPrismRig(
        alpha_deg=6.4,
        refractive_index=1.48,
        focal_length_mm=25.0,
        prism_thickness_mm=5.6,
        apex_distance_mm=170.0,
        pixel_size_mm=0.00465,
        image_width=1024,
        image_height=768,
    )


def thesis_setup2() -> BiPrismRig:
    """The thesis' second setup (Table 4.2): alpha 21.8 deg, f 8 mm, with a consistent thickness.

    The thesis lists T = 5.6 mm for this prism too, but a 21.8 deg prism whose back plane is 100 mm wide
    (b = 100 mm, thesis sec. 5.2) is T = 50 tan(21.8 deg) = 20.0 mm thick; with T = 5.6 mm it would be only
    2 * 5.6 / tan(21.8 deg) = 28.0 mm wide. We use T = 50 tan(alpha) so the prism is the thesis' 100 mm part.

    Example:
        >>> round(thesis_setup2().prism_thickness_mm, 2)
        20.0
    """
    alpha = 21.8
    return BiPrismRig(
        alpha_deg=alpha,
        refractive_index=1.48,
        focal_length_mm=8.0,
        prism_thickness_mm=50.0 * math.tan(math.radians(alpha)),
        apex_distance_mm=170.0,
        pixel_size_mm=0.00465,
        image_width=1024,
        image_height=768,
    )


RIG_PRESETS = {"thesis_setup1": thesis_setup1, "thesis_setup2": thesis_setup2}


def load_rig(source: str | Path | dict[str, Any]) -> BiPrismRig:
    """A validated rig from a preset name (``thesis_setup1``, ``thesis_setup2``), a JSON file path, JSON text
    (starting with ``{``) or a dict with the JSON field names.

    The user-facing way to make a rig: :meth:`BiPrismRig.from_json` / :meth:`BiPrismRig.from_dict` check the
    fields, then :func:`~prismstereo.geometry.optics.check_rig_images` checks that both half-images see through
    the prism.

    Args:
        source: a preset name, a path, JSON text or a dict.

    Returns:
        The rig.

    Raises:
        RigError: missing file, invalid JSON, invalid fields, or a half-image that sees nothing through the
            prism.

    Example:
        >>> load_rig("thesis_setup2").focal_length_mm
        8.0
        >>> load_rig(thesis_setup1().to_json()) == thesis_setup1()
        True
        >>> load_rig(thesis_setup1().replace(prism_offset_x_mm=40.0).to_dict())
        Traceback (most recent call last):
        ...
        prismstereo.errors.RigError: no pixel of the right half-image sees through the prism: ...
    """
    if isinstance(source, dict):
        rig = BiPrismRig.from_dict(source)
    elif isinstance(source, (str, Path)) and str(source) in RIG_PRESETS:
        rig = RIG_PRESETS[str(source)]()
    else:
        rig = BiPrismRig.from_json(source)
    check_rig_images(rig)
    return rig
