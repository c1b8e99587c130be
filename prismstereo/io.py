"""Reading and writing images, depth maps and ground truth (OpenCV for image files, NumPy for arrays).

Images in tensors are (C, H, W) or (B, C, H, W) float in [0, 1], RGB channel order; on disk they are 8- or
16-bit PNG/TIFF/JPEG (OpenCV's BGR order is handled here). Ground truth goes to ``.npz`` with NaN for
invalid values (see :mod:`prismstereo.conventions`). Depth maps go to ``.npy`` (float32 mm, NaN invalid) or
to 16-bit PNG as round(Z * scale), 0 invalid (scale 256: the endoscopy datasets' convention, which caps
depth at 65535 / 256 = 255.996 mm; deeper values are clipped), with a colour-mapped preview.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch

from prismstereo.errors import PrismStereoError, check_shape

__all__ = [
    "ImageIOError",
    "read_image",
    "write_image",
    "save_capture",
    "write_depth_npy",
    "write_depth_png",
    "read_depth_png",
    "write_depth_preview",
]


class ImageIOError(PrismStereoError, OSError):
    """An image file that cannot be read or written."""


def read_image(path: str | Path) -> torch.Tensor:
    """Read an 8- or 16-bit grey or colour image as a (C, H, W) float32 tensor in [0, 1] (RGB order).

    Raises:
        ImageIOError: if the file is missing or not an image OpenCV can decode.

    Example:
        >>> img = read_image("capture.png")  # doctest: +SKIP
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
        data = data[..., ::-1]  # BGR -> RGB
        tensor = torch.from_numpy(np.ascontiguousarray(data)).permute(2, 0, 1)
    else:
        tensor = torch.from_numpy(data)[None]
    return tensor.to(torch.float32) / scale


def write_image(path: str | Path, image: torch.Tensor, bits: int = 8) -> None:
    """Write a (C, H, W) image in [0, 1] (C = 1 or 3, RGB) as an 8- or 16-bit file.

    Raises:
        ImageIOError: on an unsupported bit depth or a failed write.

    Example:
        >>> write_image("out.png", torch.rand(1, 48, 64))  # doctest: +SKIP
    """
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


def _depth_array(depth: torch.Tensor, valid: torch.Tensor | None) -> np.ndarray:
    """(H, W) float64 numpy depth with NaN where invalid or non-finite."""
    check_shape(depth, ["H", "W"], "depth")
    d = depth.detach().to(torch.float64)
    if valid is not None:
        check_shape(valid, list(depth.shape), "valid")
        d = torch.where(valid.to(torch.bool), d, torch.full_like(d, float("nan")))
    d = d.cpu().numpy()
    d[~np.isfinite(d)] = np.nan
    return d


def _imwrite(path: Path, data: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), data):
        raise ImageIOError(f"cannot write image: {path}")


def write_depth_npy(path: str | Path, depth: torch.Tensor, valid: torch.Tensor | None = None) -> None:
    """Write a depth map (H, W) in mm as a float32 ``.npy`` array, NaN where invalid or non-finite.

    Raises:
        ImageIOError: if the file cannot be written.

    Example:
        >>> write_depth_npy("depth.npy", torch.full((96, 64), 500.0))  # doctest: +SKIP
    """
    data = _depth_array(depth, valid).astype(np.float32)
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.save(path, data)
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
    if not (np.isfinite(scale) and scale > 0):
        raise ImageIOError(f"the depth PNG scale must be a positive number, got {scale!r}")
    d = _depth_array(depth, valid)
    ok = np.isfinite(d)
    levels = np.zeros(d.shape, dtype=np.float64)
    levels[ok] = np.round(d[ok] * scale)
    clipped = int((levels[ok] > 65535).sum())
    levels[ok] = np.clip(levels[ok], 1, 65535)  # a valid depth never becomes the invalid 0
    _imwrite(Path(path), levels.astype(np.uint16))
    return clipped


def read_depth_png(path: str | Path, scale: float = 256.0) -> torch.Tensor:
    """Read a 16-bit depth PNG written by :func:`write_depth_png`: (H, W) float32 mm, NaN where 0.

    Raises:
        ImageIOError: if the file is missing, not decodable, or not a single-channel 16-bit image.

    Example:
        >>> read_depth_png("depth.png").shape  # doctest: +SKIP
        torch.Size([96, 64])
    """
    path = Path(path)
    if not path.is_file():
        raise ImageIOError(f"depth image not found: {path}")
    data = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if data is None or data.dtype != np.uint16 or data.ndim != 2:
        raise ImageIOError(f"not a single-channel 16-bit depth PNG: {path}")
    depth = data.astype(np.float32) / np.float32(scale)
    depth[data == 0] = np.nan
    return torch.from_numpy(depth)


def write_depth_preview(
    path: str | Path,
    depth: torch.Tensor,
    valid: torch.Tensor | None = None,
    cmap: str = "turbo",
    percentiles: tuple[float, float] = (2.0, 98.0),
) -> None:
    """Write an 8-bit RGB picture of a depth map (H, W): a matplotlib colormap of inverse depth (near warm,
    far cool with ``turbo``) stretched between the given percentiles of the valid depths; invalid pixels black.

    Raises:
        ImageIOError: on an unknown colormap or a failed write.

    Example:
        >>> write_depth_preview("depth_preview.png", 400 + 100 * torch.rand(96, 64))  # doctest: +SKIP
    """
    import matplotlib

    try:
        colormap = matplotlib.colormaps[cmap]
    except KeyError as exc:
        raise ImageIOError(f"unknown matplotlib colormap {cmap!r}") from exc
    d = _depth_array(depth, valid)
    ok = np.isfinite(d) & (d > 0)
    inv = np.zeros(d.shape)
    inv[ok] = 1.0 / d[ok]
    lo, hi = np.percentile(inv[ok], percentiles) if ok.any() else (0.0, 1.0)
    t = np.clip((inv - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    rgb = colormap(t)[..., :3]
    rgb[~ok] = 0.0
    _imwrite(Path(path), np.ascontiguousarray((rgb[..., ::-1] * 255).round().astype(np.uint8)))
