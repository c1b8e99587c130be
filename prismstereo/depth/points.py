"""Point clouds from depth maps of the reference view, and binary PLY files.

A reference pixel (u, v) sees the scene along the ray it leaves the prism's left face with
(:func:`~prismstereo.geometry.optics.trace_pixels`, thesis R1 -> R2 -> R3, eq. 3.1-3.10); its point at depth
Z is where that ray reaches the plane z = Z (:func:`~prismstereo.geometry.optics.points_at_depth`):
X = o + (Z - o_z) / d_z d, with o the exit point on the back plane and d the outgoing direction. This is
exact (no virtual pinhole), so projecting the points back through the left face recovers the pixel grid.

PLY files (:func:`write_ply`, :func:`read_ply`) are binary little-endian with one ``vertex`` element:
float32 ``x y z`` (mm; the camera frame, or a world frame given by a camera-to-world transform), optionally uchar
``red green blue`` and a float32 ``confidence`` (the depth model's, as MeshLab and Open3D read scalar
properties).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from prismstereo.errors import PrismStereoError, ShapeError, check_floating, check_shape
from prismstereo.geometry.optics import points_at_depth, trace_pixels
from prismstereo.geometry.parameters import RigParameters
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.io import replacing

__all__ = ["PointCloud", "PointCloudError", "depth_to_points", "write_ply", "read_ply"]


class PointCloudError(PrismStereoError, OSError):
    """A PLY file that cannot be written or read (or is not the binary form :func:`write_ply` writes)."""


class PointCloud(NamedTuple):
    """Points read from a PLY file.

    Attributes:
        points: (N, 3) float32 camera-frame points (mm).
        colors: (N, 3) uint8 RGB, or None if the file has no colours.
        confidence: (N,) float32, or None if the file has no ``confidence`` property.
    """

    points: torch.Tensor
    colors: torch.Tensor | None
    confidence: torch.Tensor | None = None


def depth_to_points(
    rig: BiPrismRig | RigParameters, depth: torch.Tensor, valid: torch.Tensor | None = None
) -> torch.Tensor:
    """Camera-frame 3D points of the reference pixels from their depth, by exact ray tracing.

    X(u, v) = o + (Z - o_z) / d_z d for the ray (o, d) of pixel (u, v) leaving the left prism face (module
    docstring; thesis eq. 3.1-3.10). Pixels with NaN or non-finite depth, ``valid`` False, or a ray that
    misses the prism give NaN points. Differentiable w.r.t. ``depth`` and the rig's parameters (the NaN
    entries are selected after the computation, from a finite stand-in depth, so no NaN reaches a gradient).

    Args:
        rig: the rig (:class:`BiPrismRig`, or :class:`RigParameters` that may require grad).
        depth: (B, 1, H, W_ref) depth Z (mm) of the reference half, W_ref = ``rig.reference_width``.
        valid: optional (B, 1, H, W_ref) bool mask of usable depths.

    Returns:
        (B, 3, H, W_ref) points (x, y, z) in mm, dtype and device of ``depth``; z equals ``depth`` where finite.

    Raises:
        ShapeError: if ``depth`` is not (B, 1, rig height, W_ref) or ``valid`` does not match it.

    Example:
        >>> small = thesis_setup1().downscaled(8)
        >>> pts = depth_to_points(small, torch.full((1, 1, 96, 64), 500.0))
        >>> pts.shape
        torch.Size([1, 3, 96, 64])
    """
    check_shape(depth, ["B", 1, "H", "W"], "depth")
    check_floating(depth, "depth")
    height = rig.image_height if isinstance(rig, BiPrismRig) else rig.height
    w_ref = rig.reference_width
    if depth.shape[-2:] != (height, w_ref):
        raise ShapeError(f"depth must cover the reference half, (B, 1, {height}, {w_ref}) for this rig, "
                         f"got {tuple(depth.shape)}")
    ok = torch.isfinite(depth)
    if valid is not None:
        check_shape(valid, list(depth.shape), "valid")
        ok = ok & valid.to(torch.bool)
    u = torch.arange(w_ref, dtype=depth.dtype, device=depth.device)
    v = torch.arange(height, dtype=depth.dtype, device=depth.device)
    uv = torch.stack(torch.meshgrid(u, v, indexing="xy"), -1)  # (H, W_ref, 2)
    rays = trace_pixels(rig, uv, "left")
    ok = ok & rays.valid
    safe = torch.where(ok, depth, torch.full_like(depth, 1e3))[:, 0]  # (B, H, W_ref), finite everywhere
    pts = points_at_depth(rays, safe).permute(0, 3, 1, 2)  # (B, 3, H, W_ref)
    return torch.where(ok, pts, torch.full_like(pts, float("nan")))


def _per_point(values: torch.Tensor, points: torch.Tensor, name: str) -> np.ndarray:
    """(N,) float32 numpy values laid out like a mask of ``points`` ((H, W) / (1, H, W) or (N,))."""
    grid = points.dim() == 3 and points.shape[0] == 3
    want = tuple(points.shape[1:]) if grid else (points.shape[0],)
    n = int(np.prod(want))
    if not isinstance(values, torch.Tensor) or values.numel() != n or values.dim() not in (len(want), len(want) + 1):
        got = tuple(values.shape) if isinstance(values, torch.Tensor) else type(values).__name__
        raise ShapeError(f"{name} must have shape {want}, got {got}")
    return values.detach().reshape(-1).to(torch.float32).cpu().numpy()


def _as_rows(points: torch.Tensor, valid: torch.Tensor | None, colors: torch.Tensor | None):
    """(N, 3) float32 points, (N,) keep mask and (N, 3) uint8 colours (or None) as numpy arrays."""
    if not isinstance(points, torch.Tensor):
        raise ShapeError(f"points must be a torch.Tensor, got {type(points).__name__}")
    grid = points.dim() == 3 and points.shape[0] == 3
    if grid:
        check_shape(points, [3, "H", "W"], "points")
        pts = points.detach().permute(1, 2, 0).reshape(-1, 3)
    else:
        check_shape(points, ["N", 3], "points")
        pts = points.detach()
    keep = torch.isfinite(pts).all(-1)
    if valid is not None:
        want = list(points.shape[1:]) if grid else [points.shape[0]]
        if not isinstance(valid, torch.Tensor) or valid.numel() != pts.shape[0] or (
                valid.dim() not in (len(want), len(want) + 1)):
            raise ShapeError(f"valid must have shape {tuple(want)}, got "
                             f"{tuple(valid.shape) if isinstance(valid, torch.Tensor) else type(valid).__name__}")
        keep = keep & valid.detach().reshape(-1).to(torch.bool).cpu()
    rgb = None
    if colors is not None:
        if grid:
            check_shape(colors, ["C", *points.shape[1:]], "colors")
            c = colors.detach().permute(1, 2, 0).reshape(-1, colors.shape[0])
        else:
            check_shape(colors, [points.shape[0], "C"], "colors")
            c = colors.detach()
        if c.shape[-1] not in (1, 3):
            raise ShapeError(f"colors must have 1 (grey) or 3 (RGB) channels, got {c.shape[-1]}")
        if torch.is_floating_point(c):
            c = (c.clamp(0, 1) * 255).round()
        rgb = c.to(torch.uint8).expand(-1, 3).cpu().numpy()
    return pts.cpu().to(torch.float32).numpy(), keep.cpu().numpy(), rgb


def write_ply(
    path: str | Path,
    points: torch.Tensor,
    valid: torch.Tensor | None = None,
    colors: torch.Tensor | None = None,
    *,
    confidence: torch.Tensor | None = None,
    camera_to_world: torch.Tensor | None = None,
) -> int:
    """Write the valid, finite points as a binary little-endian PLY file.

    Vertices are float32 ``x y z`` (mm), plus uchar ``red green blue`` when ``colors`` is given and a float32
    ``confidence`` when ``confidence`` is.

    Args:
        path: output ``.ply`` path (parent folders are created).
        points: (3, H, W) points of an image (e.g. one item of :func:`depth_to_points`) or (N, 3) points, in the
            camera frame (mm).
        valid: optional mask, (H, W) or (1, H, W) for image points, (N,) for a list; non-finite points are
            always skipped.
        colors: optional colours laid out like ``points``: (C, H, W) or (N, C), C = 1 (grey, written as
            equal RGB) or 3; floats in [0, 1] (scaled by 255 and rounded) or uint8.
        confidence: optional per-point confidence laid out like ``valid``: (H, W) / (1, H, W) or (N,).
        camera_to_world: optional (4, 4) rigid transform applied to the points (X_world = R X + t), e.g. the
            camera's pose on a robot or tracker; the file's comment names the frame.

    Returns:
        The number of points written.

    Raises:
        ShapeError: on mismatched shapes or a transform that is not (4, 4).
        PointCloudError: if the file cannot be written.

    Example:
        >>> write_ply("cloud.ply", torch.rand(3, 4, 5), colors=torch.rand(3, 4, 5))  # doctest: +SKIP
        20
    """
    pts, keep, rgb = _as_rows(points, valid, colors)
    frame = "camera frame"
    if camera_to_world is not None:
        if not isinstance(camera_to_world, torch.Tensor) or tuple(camera_to_world.shape) != (4, 4):
            raise ShapeError("camera_to_world must be a (4, 4) tensor, got "
                             f"{getattr(camera_to_world, 'shape', type(camera_to_world).__name__)}")
        t = camera_to_world.detach().to(torch.float64).cpu().numpy()
        pts = pts.astype(np.float64) @ t[:3, :3].T + t[:3, 3]
        frame = "world frame (camera_to_world applied)"
    conf = None
    if confidence is not None:
        conf = _per_point(confidence, points, "confidence")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if rgb is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    if conf is not None:
        fields += [("confidence", "<f4")]
    rows = np.empty(int(keep.sum()), dtype=np.dtype(fields))
    for k, name in enumerate("xyz"):
        rows[name] = pts[keep, k]
    if rgb is not None:
        for k, name in enumerate(("red", "green", "blue")):
            rows[name] = rgb[keep, k]
    if conf is not None:
        rows["confidence"] = conf[keep]
    props = "".join(f"property {'float' if kind == '<f4' else 'uchar'} {name}\n" for name, kind in fields)
    header = (f"ply\nformat binary_little_endian 1.0\ncomment prismstereo {frame}, mm\n"
              f"element vertex {rows.shape[0]}\n{props}end_header\n")
    path = Path(path)
    try:
        with replacing(path) as partial, open(partial, "wb") as fh:
            fh.write(header.encode("ascii"))
            fh.write(rows.tobytes())
    except OSError as exc:
        raise PointCloudError(f"cannot write point cloud {path}: {exc}") from exc
    return int(rows.shape[0])


_PLY_TYPES = {"float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8", "uchar": "u1", "uint8": "u1",
              "char": "i1", "int8": "i1", "ushort": "<u2", "uint16": "<u2", "short": "<i2", "int16": "<i2",
              "uint": "<u4", "uint32": "<u4", "int": "<i4", "int32": "<i4"}


def read_ply(path: str | Path) -> PointCloud:
    """Read the vertices of a binary little-endian PLY file whose only element is ``vertex`` (as
    :func:`write_ply` writes; other scalar properties are read and ignored).

    Returns:
        PointCloud(points (N, 3) float32, colors (N, 3) uint8 or None, confidence (N,) float32 or None).

    Raises:
        PointCloudError: if the file is missing, not PLY, ASCII / big-endian, has other elements or list
            properties, or is truncated.

    Example:
        >>> read_ply("cloud.ply").points.shape  # doctest: +SKIP
        torch.Size([20, 3])
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise PointCloudError(f"cannot read point cloud {path}: {exc}") from exc
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise PointCloudError(f"not a PLY file: {path}")
    lines = data[:end].decode("ascii", errors="replace").splitlines()[1:]
    count, fields = None, []
    for line in lines:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and words[1:2] != ["binary_little_endian"]:
            raise PointCloudError(f"only binary_little_endian PLY is supported, {path} is {words[1:2]}")
        if words[0] == "element":
            if words[1] != "vertex" or count is not None:
                raise PointCloudError(f"only a single 'vertex' element is supported, {path} has {words[1]!r}")
            count = int(words[2])
        if words[0] == "property":
            if words[1] == "list" or words[1] not in _PLY_TYPES:
                raise PointCloudError(f"unsupported PLY property {' '.join(words[1:])!r} in {path}")
            fields.append((words[2], _PLY_TYPES[words[1]]))
    names = [name for name, _ in fields]
    if count is None or not {"x", "y", "z"} <= set(names):
        raise PointCloudError(f"{path} has no vertex element with x, y, z")
    dtype = np.dtype(fields)
    body = data[end + len(b"end_header\n"):]
    if len(body) < count * dtype.itemsize:
        raise PointCloudError(f"{path} is truncated: {count} vertices need {count * dtype.itemsize} bytes, "
                              f"found {len(body)}")
    rows = np.frombuffer(body, dtype=dtype, count=count)
    pts = torch.from_numpy(np.stack([rows[k].astype(np.float32) for k in "xyz"], -1))
    colors = None
    if {"red", "green", "blue"} <= set(names):
        colors = torch.from_numpy(np.stack([rows[k].astype(np.uint8) for k in ("red", "green", "blue")], -1))
    confidence = torch.from_numpy(rows["confidence"].astype(np.float32)) if "confidence" in names else None
    return PointCloud(pts, colors, confidence)
