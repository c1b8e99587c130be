"""Known 3-D positions of board corners: what Tsai's method needs and what ties Zhang's cameras to the real frame.

Zhang's method sees planar boards at unknown poses; Tsai's sees a target whose 3-D points are known in the world
frame. On a bench the board's pose is measured (the thesis' motorised stand and laser sensor, sec. 3.3 and 4.3);
in a synthetic capture it is the scene's. These helpers turn a rendered checkerboard scene into the real-frame
position of each *detected* board point id, so both baselines receive their known points in the same form as
the detections (:class:`~prismstereo.calibration.targets.ViewDetection`): a (num_points, 3) tensor per view,
row k the real-frame position of board point id k (NaN where unknown).

OpenCV orders a checkerboard's corners from either end (a half turn of the ids), so ids are assigned by
projection: each true corner is projected through the rig's exact optics (:func:`~prismstereo.geometry.projection.
project_points`) and every detected corner takes the nearest one.
"""

from __future__ import annotations

import torch

from prismstereo.calibration.targets import Board, ViewDetection
from prismstereo.errors import CalibrationError
from prismstereo.geometry.projection import project_points
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.synthetic.scenes import Plane, Scene
from prismstereo.synthetic.textures import CheckerTexture

__all__ = ["checkerboard_corners", "reference_points"]

F64 = torch.float64


def checkerboard_corners(scene: Scene) -> torch.Tensor:
    """Real-frame inner corners of a checkerboard scene (:func:`~prismstereo.synthetic.scenes.checkerboard_target`,
    :func:`~prismstereo.synthetic.scenes.calibration_views`).

    Args:
        scene: a scene whose first surface is a plane textured with a checkerboard.

    Returns:
        ((rows - 1) (cols - 1), 3) float64 corners (mm), row-major over the board's rows (no OpenCV id order).

    Raises:
        CalibrationError: the scene holds no checkerboard plane.

    Example:
        >>> from prismstereo.synthetic import checkerboard_target
        >>> corners = checkerboard_corners(checkerboard_target((0.0, 0.0, 600.0), rows=8, cols=5, square_mm=6.0))
        >>> corners.shape, corners[:, 2].unique()
        (torch.Size([28, 3]), tensor([600.], dtype=torch.float64))
    """
    plane = scene.surfaces[0] if getattr(scene, "surfaces", None) else None
    if not isinstance(plane, Plane) or not isinstance(plane.texture, CheckerTexture):
        raise CalibrationError(f"scene {getattr(scene, 'name', scene)!r} is not a checkerboard target")
    tex = plane.texture
    i, j = torch.meshgrid(torch.arange(1, tex.rows, dtype=F64), torch.arange(1, tex.cols, dtype=F64), indexing="ij")
    s, t = (j.reshape(-1, 1) * tex.square_mm), (i.reshape(-1, 1) * tex.square_mm)
    return plane.point + s * plane.u_axis + t * plane.v_axis


def reference_points(
    rig: BiPrismRig, corners: torch.Tensor, detection: ViewDetection, board: Board, max_px: float = 3.0
) -> torch.Tensor:
    """Real-frame position of every detected board point id of one view.

    Args:
        rig: the rig that took the capture (exact optics to assign the ids).
        corners: (M, 3) the board's true corners in the real frame, any order (:func:`checkerboard_corners`).
        detection: the view's detection (ids shared by both halves).
        board: the target (its number of points).
        max_px: largest distance (px) between a detected corner and the projection it is assigned to.

    Returns:
        (board.num_points, 3) float64, NaN rows for ids detected in neither half.

    Raises:
        CalibrationError: the board was found in neither half, or a detected corner lies more than ``max_px`` from
            every projected true corner (wrong scene, wrong rig).

    Example:
        >>> from prismstereo.calibration import HalfDetection, parse_target
        >>> rig, board = thesis_setup1().downscaled(4), parse_target("checkerboard:4x7:6")
        >>> pts = torch.tensor([[0.0, 0.0, 600.0], [6.0, 0.0, 600.0]], dtype=torch.float64)
        >>> uv = project_points(rig, pts, "left").uv
        >>> ref = reference_points(rig, pts, ViewDetection(HalfDetection(uv.flip(0), torch.tensor([0, 1])), None),
        ...                        board)
        >>> ref[:2]
        tensor([[  6.,   0., 600.],
                [  0.,   0., 600.]], dtype=torch.float64)
    """
    if detection.left is None and detection.right is None:
        raise CalibrationError("the board was found in neither half of this view")
    out = torch.full((board.num_points, 3), float("nan"), dtype=F64)
    for half, det in (("left", detection.left), ("right", detection.right)):
        if det is None:
            continue
        proj = project_points(rig, corners.to(F64), half)
        dist = torch.cdist(det.uv.to(F64), torch.where(proj.valid[:, None], proj.uv, float("inf")))
        best, index = dist.min(dim=1)
        if not bool((best <= max_px).all()):
            raise CalibrationError(f"a detected corner of the {half} half is {float(best.max()):.2f} px from every "
                                   f"projected true corner (> {max_px} px): wrong scene or rig?")
        out[det.ids] = corners.to(F64)[index]
    return out
