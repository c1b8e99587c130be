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

Grey
    The models match grey images: a colour capture (C = 3, RGB) becomes its ITU-R BT.601 luma by :func:`to_grey`,
    the one grey rule of every model, matching stage, job and stream.
    Geometry functions accept any leading batch dims and follow the input's dtype and device.

Thesis
    Equation numbers refer to the thesis in ``shared/reference``; where its sign conventions differ from
    these (e.g. its virtual-camera frames in sec. 3.3.2), docstrings say so.
"""

from typing import Literal

import torch

from prismstereo.errors import ShapeError, check_floating, check_shape

__all__ = ["Half", "HALVES", "to_grey"]

Half = Literal["left", "right"]
HALVES: tuple[str, str] = ("left", "right")


def to_grey(image: torch.Tensor, dim: int = -3) -> torch.Tensor:
    """The grey image the models take, (*, 1, H, W), of an image (*, C, H, W) in [0, 1]: itself with one channel,
    else the ITU-R BT.601 luma of its RGB channels (weights 0.299, 0.587, 0.114): the bits of
    :func:`kornia.color.rgb_to_grayscale` (tested), computed here so that the depth path never imports kornia.

    The one grey rule of the package: every model converts a colour capture with it at its entry (a colour capture
    and its grey give the same depth), and so do the matching stages, the jobs,
    :class:`~prismstereo.stream.DepthStream` and :func:`~prismstereo.stream.video.read_frames` with ``grey=True``: a
    frame converted on a reader thread is bit for bit the frame the model would have converted. (A video's decoded
    8-bit frames take :func:`~prismstereo.stream.video.frame_to_grey`: the same weights in one pass, equal to float
    rounding.)

    Args:
        image: (*, C, H, W) with C = 1 or 3 (RGB), floating point; or any tensor with its channels on ``dim`` (the
            matching stages' (B, C, D, H, W) volumes take ``dim=1``).
        dim: the channel axis.

    Returns:
        (*, 1, H, W) (the channel axis kept, of size 1), ``image`` itself when C = 1.

    Raises:
        ShapeError: C is neither 1 nor 3. PrismStereoError (a ``TypeError``): an integer image.

    Example:
        >>> to_grey(torch.tensor([1.0, 0.0, 0.0]).view(3, 1, 1)).flatten().tolist()
        [0.29899999499320984]
        >>> to_grey(torch.rand(2, 3, 4, 5, 6), dim=1).shape
        torch.Size([2, 1, 4, 5, 6])
    """
    if dim == -3:
        check_shape(image, ["*", "C", "H", "W"], "image")
    check_floating(image, "image")
    channels = image.shape[dim]
    if channels == 1:
        return image
    if channels != 3:
        raise ShapeError(f"image must have 1 (grey) or 3 (RGB) channels, got {channels}")
    r, g, b = image.unbind(dim)
    w_r, w_g, w_b = torch.tensor([0.299, 0.587, 0.114], dtype=image.dtype).to(image.device).unbind()
    return torch.addcmul(torch.addcmul(r * w_r, g, w_g), b, w_b).unsqueeze(dim)  # kornia's order of operations
