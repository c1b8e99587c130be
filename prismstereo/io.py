"""Reading and writing images and ground truth (OpenCV for image files, NumPy for arrays).

Images in tensors are (C, H, W) or (B, C, H, W) float in [0, 1], RGB channel order; on disk they are 8- or
16-bit PNG/TIFF/JPEG (OpenCV's BGR order is handled here). Ground truth goes to ``.npz`` with NaN for
invalid values (see :mod:`prismstereo.conventions`).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch

from prismstereo.errors import PrismStereoError, check_shape

__all__ = ["ImageIOError", "read_image", "write_image", "save_capture"]


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
