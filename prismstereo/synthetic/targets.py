"""Calibration targets at any pose: checkerboard, ChArUco and circle-grid boards as bounded textured planes, and
seeded board poses for calibration captures. The scenes render like any other (:mod:`prismstereo.synthetic.render`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import torch

from prismstereo.geometry.surfaces import euler_rotation
from prismstereo.synthetic.scenes import Plane, Scene, vector3
from prismstereo.synthetic.textures import CheckerTexture, CircleGridTexture, ImageTexture, SceneError, Texture

__all__ = ["checkerboard_target", "charuco_target", "circle_grid_target", "calibration_views"]

F64 = torch.float64


def _target(texture: Texture, size: tuple[float, float], margin: float, centre_mm, rotation_deg) -> Plane:
    """A bounded plane whose texture origin is the pattern's corner, posed by rotation then translation."""
    rot = euler_rotation(torch.tensor([math.radians(a) for a in rotation_deg], dtype=F64))
    centre = vector3(centre_mm, "centre_mm")
    corner = centre - rot[:, 0] * size[0] / 2 - rot[:, 1] * size[1] / 2
    return Plane(corner.tolist(), rot[:, 2].tolist(), texture, u_axis=rot[:, 0].tolist(),
                 bounds_mm=(-margin, size[0] + margin, -margin, size[1] + margin))


def checkerboard_target(
    centre_mm: Sequence[float] = (0.0, 0.0, 600.0), rotation_deg: Sequence[float] = (0.0, 0.0, 0.0),
    rows: int = 7, cols: int = 10, square_mm: float = 10.0, background: float = 0.5,
) -> Scene:
    """A checkerboard (``rows`` x ``cols`` squares, one white square of margin) at any pose.

    The board's axes are the camera's rotated by ``rotation_deg`` (about x, y, z: R_z R_y R_x); inner corner
    (i, j) sits at corner + (j + 1) square u + (i + 1) square v.

    Example:
        >>> checkerboard_target(rows=6, cols=9).name
        'checkerboard_6x9'
    """
    texture = CheckerTexture(rows, cols, square_mm)
    plane = _target(texture, (cols * square_mm, rows * square_mm), square_mm, centre_mm, rotation_deg)
    return Scene([plane], background=background, name=f"checkerboard_{rows}x{cols}")


def charuco_target(
    centre_mm: Sequence[float] = (0.0, 0.0, 600.0), rotation_deg: Sequence[float] = (0.0, 0.0, 0.0),
    cols: int = 16, rows: int = 12, square_mm: float = 8.0, marker_mm: float = 6.0,
    dictionary: str = "DICT_4X4_250", texels_per_square: int = 40, background: float = 0.5,
) -> Scene:
    """A ChArUco board (``cols`` x ``rows`` squares, OpenCV's ``CharucoBoard``) with one white square of margin, at
    any pose: a board larger than either half's view, as a calibration target seen partly by each half.

    Board point (x, y) of OpenCV's ``getChessboardCorners`` (origin at the board's outer corner, x along the
    columns, y along the rows) sits at surface coordinates (x + square_mm, y + square_mm) of the plane, whose axes
    are the camera's rotated by ``rotation_deg`` (as :func:`checkerboard_target`); the plane's surface origin is
    the margin's corner.

    Example:
        >>> charuco_target(cols=5, rows=4).name
        'charuco_5x4'
    """
    dictionary_id = getattr(cv2.aruco, dictionary, None)
    if dictionary_id is None or not dictionary.startswith("DICT_"):
        raise SceneError(f"unknown ArUco dictionary {dictionary!r}")
    board = cv2.aruco.CharucoBoard((cols, rows), square_mm, marker_mm, cv2.aruco.getPredefinedDictionary(dictionary_id))
    t = texels_per_square
    picture = board.generateImage(((cols + 2) * t, (rows + 2) * t), marginSize=t)
    texture = ImageTexture(torch.from_numpy(picture).float() / 255.0, (cols + 2) * square_mm, (rows + 2) * square_mm)
    size = ((cols + 2) * square_mm, (rows + 2) * square_mm)
    rot = euler_rotation(torch.tensor([math.radians(a) for a in rotation_deg], dtype=F64))
    corner = vector3(centre_mm, "centre_mm") - rot[:, 0] * size[0] / 2 - rot[:, 1] * size[1] / 2
    plane = Plane(corner.tolist(), rot[:, 2].tolist(), texture, u_axis=rot[:, 0].tolist(),
                  bounds_mm=(0.0, size[0], 0.0, size[1]))
    return Scene([plane], background=background, name=f"charuco_{cols}x{rows}")


def circle_grid_target(
    centre_mm: Sequence[float] = (0.0, 0.0, 600.0), rotation_deg: Sequence[float] = (0.0, 0.0, 0.0),
    rows: int = 6, cols: int = 9, spacing_mm: float = 12.0, radius_mm: float = 3.5, background: float = 0.5,
) -> Scene:
    """A symmetric grid of black circles on a white board at any pose (see :func:`checkerboard_target`).

    Example:
        >>> circle_grid_target().name
        'circlegrid_6x9'
    """
    texture = CircleGridTexture(rows, cols, spacing_mm, radius_mm)
    plane = _target(texture, (cols * spacing_mm, rows * spacing_mm), spacing_mm / 2, centre_mm, rotation_deg)
    return Scene([plane], background=background, name=f"circlegrid_{rows}x{cols}")


def calibration_views(
    n: int, seed: int = 0, depth_range_mm: tuple[float, float] = (550.0, 850.0), max_tilt_deg: float = 45.0,
    rows: int = 8, cols: int = 5, square_mm: float = 6.0, spread_mm: tuple[float, float] = (3.0, 15.0),
    kind: str = "checkerboard", marker_mm: float | None = None, dictionary: str = "DICT_4X4_250",
) -> list[Scene]:
    """``n`` boards at seeded random poses for calibration captures: depths uniform in ``depth_range_mm``, tilts
    uniform within +-``max_tilt_deg`` about x and y and +-10 deg about z, centres within +-``spread_mm`` of the axis.

    ``kind`` 'checkerboard' (:func:`checkerboard_target`, ``rows`` x ``cols`` squares): the defaults fit a 5 x 8-square
    board of 6 mm (4 x 7 inner corners) into the common field of view of ``thesis_setup1``'s halves, as a board must
    be seen whole. 'charuco' (:func:`charuco_target`, ``rows`` x ``cols`` squares of ``square_mm``, markers of
    ``marker_mm``, default 3/4 of a square, from ``dictionary``): a board larger than the views, seen partly by each
    half, e.g. ``rows=12, cols=16, square_mm=8``. Strong tilts are what make a narrow-angle camera's focal length
    observable.

    Example:
        >>> [s.name for s in calibration_views(2)]
        ['checkerboard_8x5', 'checkerboard_8x5']
    """
    if kind not in ("checkerboard", "charuco"):
        raise SceneError(f"unknown board kind {kind!r}; valid: checkerboard, charuco")
    g = torch.Generator().manual_seed(seed)
    scenes = []
    for _ in range(n):
        z = depth_range_mm[0] + (depth_range_mm[1] - depth_range_mm[0]) * float(torch.rand(1, generator=g))
        rx, ry, rz = ((torch.rand(3, generator=g) * 2 - 1) * torch.tensor([max_tilt_deg, max_tilt_deg, 10.0])).tolist()
        x, y = ((torch.rand(2, generator=g) * 2 - 1) * torch.tensor(spread_mm)).tolist()
        if kind == "checkerboard":
            scenes.append(checkerboard_target((x, y, z), (rx, ry, rz), rows=rows, cols=cols, square_mm=square_mm))
        else:
            scenes.append(charuco_target((x, y, z), (rx, ry, rz), cols=cols, rows=rows, square_mm=square_mm,
                                         marker_mm=marker_mm or 0.75 * square_mm, dictionary=dictionary))
    return scenes
