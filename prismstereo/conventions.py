"""The conventions every prismstereo function follows (tests and users depend on them).

Frames
    Camera frame: x right, y down, z forward (OpenCV / Kornia); origin at the real camera's optical
    centre. Every 3D point and ray of the library is in this frame unless a docstring says otherwise.
    Virtual cameras (:mod:`prismstereo.geometry.virtual_camera`) have extrinsics mapping this frame to
    theirs, X_vc = R^T (X - C).

Units
    Lengths in mm; angles in radians internally; degrees only in user-facing fields named ``*_deg``.

Pixels
    (u, v) = (column, row); pixel centres at integer coordinates, so a W-pixel row spans u in
    [-0.5, W - 0.5]; principal point (cx, cy) defaults to ((W - 1) / 2, (H - 1) / 2).

Prism
    Apex line parallel to y at x = d (``prism_offset_x_mm``), z = T_o (``apex_distance_mm``); faces
    z = T_o + |x - d| tan(alpha); back plane z = T_o + T (``prism_thickness_mm``) parallel to the image
    plane; glass index n. Rays entering through the face at x < d form the **left half-image**, which is
    the **reference view**. An optional tilt rotates the prism about its apex point (d, 0, T_o).

Depth and validity
    Depth = Z (mm, camera frame) of the scene point a pixel sees. Invalid values are NaN in files and
    come with a boolean ``valid`` mask in tensors; no NaN is ever produced inside a differentiable path.

Shapes
    Letters used in docstrings: B batch, C channels, H rows, W columns, W_ref columns of the reference
    half, N points, D depth hypotheses, ``*`` any leading dims. Images are (B, C, H, W) floats in [0, 1].
    Geometry functions accept any leading batch dims and follow the input's dtype and device.

Thesis
    Equation numbers refer to the thesis in ``shared/reference``; where its sign conventions differ from
    these (e.g. its virtual-camera frames in sec. 3.3.2), docstrings say so.
"""

from typing import Literal

__all__ = ["Half", "HALVES"]

Half = Literal["left", "right"]
HALVES: tuple[str, str] = ("left", "right")
