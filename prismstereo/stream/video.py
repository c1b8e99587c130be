"""Frames of a video file or an image sequence, for depth over time (``prismstereo depth VIDEO``, :class:`DepthStream`).

A source is a video file (whatever OpenCV's ``VideoCapture`` reads: .mp4, .avi, .mkv, ...), a directory of images
(sorted by name) or a glob pattern of images (``frames/*.png``). Frames come back as (C, H, W) float tensors in
[0, 1], RGB (as :func:`~prismstereo.io.read_image`), numbered by their position in the source, with ``every`` /
``start`` / ``stop`` selecting which. What a source is, its files and length: :mod:`prismstereo.sources`.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from prismstereo.sources import (
    IMAGE_SUFFIXES,
    VIDEO_SUFFIXES,
    Frame,
    VideoError,
    bgr_to_grey,
    bgr_to_rgb,
    check_selection,
    decode_frames,
    is_sequence_source,
    is_video_file,
    sequence_files,
    sequence_length,
    sequence_name,
)

__all__ = ["VideoError", "Frame", "VIDEO_SUFFIXES", "IMAGE_SUFFIXES", "is_sequence_source", "is_video_file",
           "sequence_name", "sequence_files", "sequence_length", "check_selection", "frame_to_tensor", "frame_to_grey",
           "read_frames"]
# the sources themselves (suffixes, names, files, lengths, selections, frames as arrays) are prismstereo.sources',
# importable without torch; they stay importable from here


def frame_to_tensor(bgr: np.ndarray) -> torch.Tensor:
    """A decoded 8-bit frame, OpenCV's uint8 (H, W) or (H, W, 3) BGR, as (C, H, W) float32 RGB in [0, 1]
    (:func:`~prismstereo.sources.bgr_to_rgb` as a tensor).

    Raises:
        ShapeError: not such an array.

    Example:
        >>> frame_to_tensor(np.zeros((4, 5, 3), np.uint8)).shape
        torch.Size([3, 4, 5])
    """
    return torch.from_numpy(bgr_to_rgb(bgr))


def frame_to_grey(frame: np.ndarray) -> torch.Tensor:
    """A decoded 8-bit frame, OpenCV's uint8 (H, W) or (H, W, 3) BGR, as the (1, H, W) float32 grey image in [0, 1]
    that a one-channel model takes (:func:`~prismstereo.sources.bgr_to_grey` as a tensor): the conversion of video
    frames for grey models, on the reader thread (:func:`read_frames` with ``grey=True``) and in
    :class:`~prismstereo.stream.DepthStream` alike, so the two give the same bits.

    Raises:
        ShapeError: not such an array.

    Example:
        >>> frame_to_grey(np.full((2, 3, 3), 255, np.uint8)).shape
        torch.Size([1, 2, 3])
    """
    return torch.from_numpy(bgr_to_grey(frame))


def read_frames(source: str | Path, *, every: int = 1, start: int = 0, stop: int | None = None,
                grey: bool = False, decode_threads: int | None = None) -> Iterator[Frame]:
    """The frames ``start``, ``start + every``, ... (< ``stop``) of a video file, directory or glob of images, as
    tensors: :func:`~prismstereo.sources.decode_frames`' frames (the same bits), each image a tensor.

    Args:
        source, every, start, stop, grey, decode_threads: as :func:`~prismstereo.sources.decode_frames` (``grey``:
            bit for bit what :class:`~prismstereo.stream.DepthStream` makes of the decoded frame or the image).

    Yields:
        Frame(index, image (C, H, W) float32 tensor in [0, 1], name).

    Raises:
        VideoError: a missing, unopenable or empty source, bad selection, or a frame that cannot be decoded.

    Example:
        >>> [f.index for f in read_frames("frames/", every=2, stop=5)]  # doctest: +SKIP
        [0, 2, 4]
    """
    for frame in decode_frames(source, every=every, start=start, stop=stop, grey=grey, decode_threads=decode_threads):
        yield frame._replace(image=torch.from_numpy(frame.image))
