"""Reading and writing images, depth maps and ground truth (OpenCV for image files, NumPy for arrays).

Images in tensors are (C, H, W) or (B, C, H, W) float in [0, 1], RGB channel order; on disk they are 8- or
16-bit PNG/TIFF/JPEG (OpenCV's BGR order is handled here). Ground truth goes to ``.npz`` with NaN for
invalid values (see :mod:`prismstereo.conventions`). Depth maps (:func:`write_depth`, :func:`read_depth`) go to
``.npy`` or float32 ``.tiff`` (mm, NaN invalid, lossless) or to 16-bit PNG as round(Z * scale), 0 invalid. The
endoscopy datasets' scale 256 caps depth at 65535 / 256 = 255.996 mm; when the depths do not fit, the scale is
the largest power of two that does (:func:`depth_png_scale`), stored in the PNG (text chunk
``prismstereo.depth_scale``) and in a sidecar ``.json``, where :func:`read_depth` finds it. OpenEXR is not
offered: this OpenCV build has no EXR writer. Colour-mapped previews: :mod:`prismstereo.preview`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import cv2
import numpy as np

from prismstereo.errors import PrismStereoError, ShapeError, check_shape
from prismstereo.files import partial_stem, replacing

if TYPE_CHECKING:  # the tensor functions import it as they run: writing depth maps from arrays needs no torch
    import torch
from prismstereo.names import DEPTH_FILE_FORMATS, DEPTH_SUFFIXES

__all__ = [
    "ImageIOError",
    "decode_image",
    "grey_array",
    "read_image",
    "write_image",
    "save_capture",
    "write_depth_npy",
    "write_depth_png",
    "read_depth_png",
    "DEPTH_FILE_FORMATS",
    "DEPTH_SUFFIXES",
    "DepthFile",
    "depth_png_scale",
    "write_depth",
    "read_depth",
    "replacing",
    "partial_stem",
]

SCALE_KEY = "prismstereo.depth_scale"


class ImageIOError(PrismStereoError, OSError):
    """An image file that cannot be read or written."""


def read_image(path: str | Path) -> torch.Tensor:
    """Read an 8- or 16-bit grey or colour image as a (C, H, W) float32 tensor in [0, 1] (RGB order): the tensor of
    :func:`decode_image`.

    Raises:
        ImageIOError: if the file is missing or not an image OpenCV can decode.

    Example:
        >>> img = read_image("capture.png")  # doctest: +SKIP
    """
    import torch

    return torch.from_numpy(decode_image(path))


def decode_image(path: str | Path) -> np.ndarray:
    """An 8- or 16-bit grey or colour image as a (C, H, W) float32 numpy array in [0, 1] (RGB order), without torch.

    Raises:
        ImageIOError: if the file is missing or not an image OpenCV can decode.

    Example:
        >>> decode_image("capture.png").dtype  # doctest: +SKIP
        dtype('float32')
    """
    path = Path(path)
    if not path.is_file():
        raise ImageIOError(f"image not found: {path}")
    data = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if data is None:
        raise ImageIOError(f"cannot decode image: {path}")
    if data.dtype == np.uint8:
        scale = 255.0
    elif data.dtype == np.uint16:
        scale = 65535.0
    else:
        raise ImageIOError(f"unsupported image depth {data.dtype} in {path} (need 8 or 16 bit)")
    if data.ndim == 3:
        if data.shape[2] == 4:
            data = data[..., :3]
        data = data[..., ::-1].transpose(2, 0, 1)  # BGR -> RGB, channels first
    else:
        data = data[None]
    return np.ascontiguousarray(data, dtype=np.float32) / np.float32(scale)


_LUMA = np.array([0.299, 0.587, 0.114], dtype=np.float32)


def grey_array(image: np.ndarray) -> np.ndarray:
    """:func:`~prismstereo.conventions.to_grey` of a float32 numpy array, (..., C, H, W) -> (..., 1, H, W), bit for bit
    without torch: the BT.601 luma (0.299, 0.587, 0.114) in torch's order of operations, its two fused multiply-adds
    rounded once each (a float32 product is exact in float64, so the float64 sum rounded to float32 is the fused
    result; tested against torch on 8-bit, 16-bit and random images). A one-channel image is returned as it is.

    Raises:
        ShapeError: C is neither 1 nor 3, or not float32.

    Example:
        >>> grey_array(np.ones((3, 2, 2), np.float32)).shape
        (1, 2, 2)
    """
    if not isinstance(image, np.ndarray) or image.ndim < 3 or image.dtype != np.float32 or image.shape[-3] not in (
            1, 3):
        got = f"{image.dtype} {image.shape}" if isinstance(image, np.ndarray) else type(image).__name__
        raise ShapeError(f"image must be a float32 (..., C, H, W) array with C = 1 or 3, got {got}")
    if image.shape[-3] == 1:
        return image
    r, g, b = (image[..., c, :, :] for c in range(3))
    w_r, w_g, w_b = (np.float64(w) for w in _LUMA)
    partial = (g * w_g + (r * _LUMA[0]).astype(np.float64)).astype(np.float32)  # addcmul(r * w_r, g, w_g)
    return (b * w_b + partial.astype(np.float64)).astype(np.float32)[..., None, :, :]


def write_image(path: str | Path, image: torch.Tensor, bits: int = 8) -> None:
    """Write a (C, H, W) image in [0, 1] (C = 1 or 3, RGB) as an 8- or 16-bit file.

    Raises:
        ImageIOError: on an unsupported bit depth or a failed write.

    Example:
        >>> write_image("out.png", torch.rand(1, 48, 64))  # doctest: +SKIP
    """
    import torch

    check_shape(image, ["C", "H", "W"], "image")
    if bits not in (8, 16) or image.shape[0] not in (1, 3):
        raise ImageIOError(f"need bits 8 or 16 and 1 or 3 channels, got {bits} bits, {image.shape[0]} channels")
    levels = 2**bits - 1
    data = (image.detach().clamp(0, 1) * levels).round().to(torch.int64).numpy()
    data = data.astype(np.uint8 if bits == 8 else np.uint16)
    data = data[0] if data.shape[0] == 1 else np.ascontiguousarray(data.transpose(1, 2, 0)[..., ::-1])
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), data):
        raise ImageIOError(f"cannot write image: {path}")


def save_capture(capture, index: int, image_path: str | Path, bits: int = 8, metadata: dict | None = None) -> Path:
    """Write one capture of a batch: the image, and its ground truth next to it as ``<stem>.npz``.

    The ``.npz`` holds float32 ``depth`` (H, W), ``points`` (H, W, 3), ``match_uv`` (H, W, 2) with NaN where
    invalid, boolean ``valid``, ``left``, ``covisible`` (H, W), and the ``metadata`` entries as strings.

    Returns:
        The path of the ``.npz`` file.

    Example:
        >>> save_capture(cap, 0, "capture.png")  # doctest: +SKIP
    """
    image_path = Path(image_path)
    write_image(image_path, capture.image[index], bits)
    npz_path = image_path.with_suffix(".npz")
    arrays = {
        "depth": capture.depth[index, 0].numpy().astype(np.float32),
        "points": capture.points[index].permute(1, 2, 0).numpy().astype(np.float32),
        "match_uv": capture.match_uv[index].permute(1, 2, 0).numpy().astype(np.float32),
        "valid": capture.valid[index, 0].numpy(),
        "left": capture.left[index, 0].numpy(),
        "covisible": capture.covisible[index, 0].numpy(),
    }
    arrays.update({k: np.array(str(v)) for k, v in (metadata or {}).items()})
    np.savez_compressed(npz_path, **arrays)
    return npz_path


def _depth_array(depth: Any, valid: Any | None, dtype: type = np.float64) -> np.ndarray:
    """(H, W) numpy depth of ``dtype`` with NaN where invalid or non-finite, from (H, W) tensors or arrays."""
    d, v = (x.detach().cpu().numpy() if hasattr(x, "detach") else x for x in (depth, valid))
    d = np.array(d, dtype=dtype)  # a copy
    if d.ndim != 2 or (v is not None and np.shape(v) != d.shape):
        name, want, got = ("depth", "(H, W)", d.shape) if d.ndim != 2 else ("valid", tuple(d.shape), np.shape(v))
        raise ShapeError(f"{name} must have shape {want}, got {tuple(got)}")
    d[~np.isfinite(d) | (False if v is None else ~np.asarray(v, dtype=bool))] = np.nan
    return d


def _imwrite(path: Path, data: np.ndarray) -> None:
    try:
        with replacing(path) as partial:
            if not cv2.imwrite(str(partial), data):
                raise ImageIOError(f"cannot write image: {path}")
    except OSError as exc:
        if isinstance(exc, ImageIOError):
            raise
        raise ImageIOError(f"cannot write image {path}: {exc}") from exc


def write_depth_npy(path: str | Path, depth: torch.Tensor, valid: torch.Tensor | None = None) -> None:
    """Write a depth map (H, W) in mm as a float32 ``.npy`` array, NaN where invalid or non-finite.

    Raises:
        ImageIOError: if the file cannot be written.

    Example:
        >>> write_depth_npy("depth.npy", torch.full((96, 64), 500.0))  # doctest: +SKIP
    """
    data = _depth_array(depth, valid, np.float32)
    path = Path(path)
    try:
        with replacing(path) as partial:
            np.save(partial, data)
    except OSError as exc:
        raise ImageIOError(f"cannot write depth map {path}: {exc}") from exc


def write_depth_png(
    path: str | Path, depth: torch.Tensor, valid: torch.Tensor | None = None, scale: float = 256.0
) -> int:
    """Write a depth map (H, W) in mm as a 16-bit PNG of round(Z * scale) clipped to [1, 65535], 0 invalid.

    Args:
        path: output ``.png``.
        depth: (H, W) depth Z (mm); NaN / non-finite / ``valid`` False are written as 0.
        valid: optional (H, W) bool mask.
        scale: levels per mm (default 256, the endoscopy convention: 1/256 mm steps up to 255.996 mm).

    Returns:
        The number of valid pixels clipped at 65535 (depth beyond 65535 / scale mm).

    Raises:
        ImageIOError: on a non-positive scale or a failed write.

    Example:
        >>> write_depth_png("depth.png", torch.full((96, 64), 200.0))  # doctest: +SKIP
        0
    """
    levels, clipped = _png_levels(depth, valid, scale)
    _imwrite(Path(path), levels)
    return clipped


def _png_levels(depth: torch.Tensor, valid: torch.Tensor | None, scale: float) -> tuple[np.ndarray, int]:
    """(H, W) uint16 round(Z * scale) clipped to [1, 65535], 0 invalid; and how many valid pixels were clipped."""
    if not (np.isfinite(scale) and scale > 0):
        raise ImageIOError(f"the depth PNG scale must be a positive number, got {scale!r}")
    d = _depth_array(depth, valid)
    ok = np.isfinite(d)
    levels = np.zeros(d.shape, dtype=np.float64)
    levels[ok] = np.round(d[ok] * scale)
    clipped = int((levels[ok] > 65535).sum())
    levels[ok] = np.clip(levels[ok], 1, 65535)  # a valid depth never becomes the invalid 0
    return levels.astype(np.uint16), clipped


def read_depth_png(path: str | Path, scale: float = 256.0) -> torch.Tensor:
    """Read a 16-bit depth PNG written by :func:`write_depth_png`: (H, W) float32 mm, NaN where 0.

    Raises:
        ImageIOError: if the file is missing, not decodable, or not a single-channel 16-bit image.

    Example:
        >>> read_depth_png("depth.png").shape  # doctest: +SKIP
        torch.Size([96, 64])
    """
    import torch

    path = Path(path)
    if not path.is_file():
        raise ImageIOError(f"depth image not found: {path}")
    data = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if data is None or data.dtype != np.uint16 or data.ndim != 2:
        raise ImageIOError(f"not a single-channel 16-bit depth PNG: {path}")
    depth = data.astype(np.float32) / np.float32(scale)
    depth[data == 0] = np.nan
    return torch.from_numpy(depth)


class DepthFile(NamedTuple):
    """What :func:`write_depth` wrote.

    Attributes:
        path: the depth file.
        format: 'npy', 'png' or 'tiff'.
        scale: the PNG's levels per mm (None for float formats).
        sidecar: the PNG's sidecar JSON holding the scale (None for float formats).
        clipped: valid pixels clipped at 65535 (PNG with an explicit scale too small for them).
    """

    path: Path
    format: str
    scale: float | None
    sidecar: Path | None
    clipped: int


def depth_png_scale(depth: torch.Tensor, valid: torch.Tensor | None = None) -> float:
    """The 16-bit PNG scale (levels per mm) for a depth map: 256 (the endoscopy convention) where every valid
    depth fits (<= 255.996 mm), else the largest power of two 2^k with max depth x 2^k <= 65535 (e.g. 32 for
    the thesis' range up to 1374 mm: 1/32 mm steps, 0.03 mm, far below the depth model's error there).

    Args:
        depth: (H, W) depth (mm).
        valid: optional (H, W) bool mask.

    Returns:
        The scale (a power of two, at most 256; 2^-k for depths beyond 65535 mm).

    Example:
        >>> depth_png_scale(torch.full((4, 4), 200.0)), depth_png_scale(torch.full((4, 4), 1374.0))
        (256.0, 32.0)
    """
    d = _depth_array(depth, valid)
    ok = np.isfinite(d) & (d > 0)
    deepest = float(d[ok].max()) if ok.any() else 0.0
    if deepest * 256.0 <= 65535.0:
        return 256.0
    return float(2.0 ** np.floor(np.log2(65535.0 / deepest)))


def _format(path: Path, format: str | None) -> str:
    by_suffix = DEPTH_SUFFIXES.get(path.suffix.lower())
    if format is None:
        if by_suffix is None:
            raise ImageIOError(f"cannot tell the depth format of {path}: use one of "
                               f"{', '.join(sorted(DEPTH_SUFFIXES))} or pass format ({', '.join(DEPTH_FILE_FORMATS)})")
        return by_suffix
    if format not in DEPTH_FILE_FORMATS:
        raise ImageIOError(f"unknown depth format {format!r}. Choose from: {', '.join(DEPTH_FILE_FORMATS)}")
    if by_suffix is not None and by_suffix != format:
        raise ImageIOError(f"format {format!r} contradicts the file name {path.name}")
    return format


def write_depth(
    path: str | Path,
    depth: torch.Tensor,
    valid: torch.Tensor | None = None,
    *,
    format: str | None = None,
    png_scale: float | None = None,
) -> DepthFile:
    """Write a depth map (H, W) in mm: ``.npy`` or ``.tiff`` float32 (NaN invalid, lossless), or a 16-bit
    ``.png`` of round(Z * scale) (0 invalid) whose scale is stored in a text chunk and a sidecar JSON
    (``<path without suffix>.json``: ``{"depth_scale": s, "units": "mm", "invalid": 0}``).

    Args:
        path: output file; its suffix gives the format unless ``format`` is given.
        depth: (H, W) depth Z (mm).
        valid: optional (H, W) bool mask (False, NaN and non-finite depths are invalid).
        format: 'npy', 'png' or 'tiff' (default: from the suffix).
        png_scale: PNG levels per mm; None picks :func:`depth_png_scale` (no clipping).

    Returns:
        DepthFile(path, format, scale, sidecar, clipped).

    Raises:
        ImageIOError: unknown or contradicting format, bad scale, failed write.

    Example:
        >>> write_depth("depth.png", torch.full((96, 64), 900.0)).scale  # doctest: +SKIP
        64.0
    """
    path = Path(path)
    fmt = _format(path, format)
    if fmt == "npy":
        write_depth_npy(path, depth, valid)
        return DepthFile(path, fmt, None, None, 0)
    if fmt == "tiff":
        _imwrite(path, _depth_array(depth, valid, np.float32))
        return DepthFile(path, fmt, None, None, 0)
    scale = depth_png_scale(depth, valid) if png_scale is None else float(png_scale)
    levels, clipped = _png_levels(depth, valid, scale)
    from PIL import Image, PngImagePlugin

    info = PngImagePlugin.PngInfo()
    info.add_text(SCALE_KEY, repr(scale))
    try:
        sidecar = path.with_suffix(".json")
        with replacing(sidecar) as partial:
            partial.write_text(json.dumps({"depth_scale": scale, "units": "mm", "invalid": 0}) + "\n")
        with replacing(path) as partial:
            Image.fromarray(levels).save(partial, format="PNG", pnginfo=info)
    except OSError as exc:
        raise ImageIOError(f"cannot write depth map {path}: {exc}") from exc
    return DepthFile(path, fmt, scale, sidecar, clipped)


def _png_scale_of(path: Path) -> float | None:
    """The scale stored by :func:`write_depth` (text chunk first, then the sidecar JSON), or None."""
    from PIL import Image

    with Image.open(path) as image:
        text = getattr(image, "text", {}) or {}
    if SCALE_KEY in text:
        return float(text[SCALE_KEY])
    sidecar = path.with_suffix(".json")
    if sidecar.is_file():
        try:
            return float(json.loads(sidecar.read_text())["depth_scale"])
        except (ValueError, KeyError, TypeError) as exc:
            raise ImageIOError(f"unreadable depth scale in {sidecar}: {exc}") from exc
    return None


def read_depth(path: str | Path, *, scale: float | None = None) -> torch.Tensor:
    """Read a depth map written by :func:`write_depth` (or any float ``.npy`` / ``.tiff`` or 16-bit ``.png``):
    (H, W) float32 mm, NaN invalid.

    Args:
        path: a ``.npy``, ``.tif``/``.tiff`` or ``.png`` file.
        scale: a PNG's levels per mm, overriding the stored one; a PNG without a stored scale is read at 256
            (the endoscopy convention).

    Returns:
        (H, W) float32 tensor.

    Raises:
        ImageIOError: missing or unreadable file, unknown suffix, wrong array shape or type.

    Example:
        >>> read_depth("depth.tiff").shape  # doctest: +SKIP
        torch.Size([768, 512])
    """
    import torch

    path = Path(path)
    fmt = _format(path, None)
    if not path.is_file():
        raise ImageIOError(f"depth map not found: {path}")
    if fmt == "png":
        stored = _png_scale_of(path) if scale is None else scale
        return read_depth_png(path, 256.0 if stored is None else stored)
    if fmt == "npy":
        try:
            data = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise ImageIOError(f"cannot read depth map {path}: {exc}") from exc
    else:
        data = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if data is None:
            raise ImageIOError(f"cannot decode depth map {path}")
    if data.ndim != 2 or not np.issubdtype(data.dtype, np.floating):
        raise ImageIOError(f"a depth map must be a 2-D float array, {path} holds {data.dtype} {data.shape}")
    return torch.from_numpy(data.astype(np.float32))
