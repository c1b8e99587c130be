"""Frames of a video file or an image sequence, for depth over time (``prismstereo depth VIDEO``, :class:`DepthStream`).

A source is a video file (whatever OpenCV's ``VideoCapture`` reads: .mp4, .avi, .mkv, ...), a directory of images
(sorted by name) or a glob pattern of images (``frames/*.png``). Frames come back as (C, H, W) float tensors in
[0, 1], RGB (as :func:`~prismstereo.io.read_image`), numbered by their position in the source, with ``every`` /
``start`` / ``stop`` selecting which. What a source is, its files and length: :mod:`prismstereo.sources`.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import torch

from prismstereo.conventions import to_grey
from prismstereo.errors import OptionError, ShapeError, check_int
from prismstereo.io import ImageIOError, read_image
from prismstereo.sources import (
    IMAGE_SUFFIXES,
    VIDEO_SUFFIXES,
    VideoError,
    check_selection,
    is_sequence_source,
    is_video_file,
    open_video,
    sequence_files,
    sequence_length,
    sequence_name,
)

__all__ = ["VideoError", "Frame", "VIDEO_SUFFIXES", "IMAGE_SUFFIXES", "is_sequence_source", "is_video_file",
           "sequence_name", "sequence_files", "sequence_length", "check_selection", "frame_to_tensor", "frame_to_grey",
           "read_frames"]
# the sources themselves (suffixes, names, files, lengths, selections) are prismstereo.sources', importable without
# torch; they stay importable from here


class Frame(NamedTuple):
    """One frame of a source.

    Attributes:
        index: position in the source (0-based; before ``every`` / ``start`` selection).
        image: (C, H, W) float32 in [0, 1], RGB or grey.
        name: the image file's name for sequences, ``"<video stem>"`` for videos.
    """

    index: int
    image: torch.Tensor
    name: str


def _check_frame(bgr: np.ndarray) -> None:
    if not isinstance(bgr, np.ndarray) or bgr.dtype != np.uint8 or bgr.ndim not in (2, 3) or (
            bgr.ndim == 3 and bgr.shape[2] != 3):
        got = f"{bgr.dtype} {bgr.shape}" if isinstance(bgr, np.ndarray) else type(bgr).__name__
        raise ShapeError(f"a decoded frame must be OpenCV's uint8 (H, W) or (H, W, 3) BGR, got {got}")


def frame_to_tensor(bgr: np.ndarray) -> torch.Tensor:
    """A decoded 8-bit frame, OpenCV's uint8 (H, W) or (H, W, 3) BGR, as (C, H, W) float32 RGB in [0, 1].

    Raises:
        ShapeError: not such an array.

    Example:
        >>> frame_to_tensor(np.zeros((4, 5, 3), np.uint8)).shape
        torch.Size([3, 4, 5])
    """
    _check_frame(bgr)
    if bgr.ndim == 2:
        return torch.from_numpy(bgr.astype(np.float32) / np.float32(255.0))[None]
    # channel order and layout on the bytes (a quarter of the memory of floats), then one conversion to float
    planes = torch.from_numpy(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)).permute(2, 0, 1).contiguous()
    return planes.to(torch.float32).div_(255.0)


# BT.601 luma weights in OpenCV's BGR order, with the 8-bit scale folded in (to_grey's weights, kornia's)
_BGR_LUMA = (np.array([[0.114, 0.587, 0.299]], dtype=np.float64) / 255.0).astype(np.float32)


def frame_to_grey(frame: np.ndarray) -> torch.Tensor:
    """A decoded 8-bit frame, OpenCV's uint8 (H, W) or (H, W, 3) BGR, as the (1, H, W) float32 grey image in [0, 1]
    that a one-channel model takes: :func:`~prismstereo.io.to_grey` of :func:`frame_to_tensor` (BT.601 weights
    0.299, 0.587, 0.114) to float rounding (at most 2e-7), in one pass over the frame instead of one per step.

    The conversion of video frames for grey models, on the reader thread (:func:`read_frames` with ``grey=True``)
    and in :class:`~prismstereo.stream.DepthStream` alike, so the two give the same bits.

    Raises:
        ShapeError: not such an array.

    Example:
        >>> frame_to_grey(np.full((2, 3, 3), 255, np.uint8)).shape
        torch.Size([1, 2, 3])
    """
    if not isinstance(frame, np.ndarray) or frame.ndim != 3:  # grey (or not a frame: its error)
        return frame_to_tensor(frame)
    _check_frame(frame)
    # cv2.transform: each pixel's weighted channel sum, one pass over the float frame (the weights carry the 1 / 255)
    return torch.from_numpy(cv2.transform(frame.astype(np.float32), _BGR_LUMA).reshape(frame.shape[:2]))[None]


def read_frames(source: str | Path, *, every: int = 1, start: int = 0, stop: int | None = None,
                grey: bool = False, decode_threads: int | None = None) -> Iterator[Frame]:
    """The frames ``start``, ``start + every``, ... (< ``stop``) of a video file, directory or glob of images.

    Args:
        source: a video file, a directory of images or a glob pattern.
        every: keep one frame in ``every``.
        start: first frame (0-based).
        stop: end (exclusive), None for the whole source.
        grey: frames as (1, H, W) grey, on the thread that reads them: what a one-channel model takes (a video's
            decoded frames by :func:`frame_to_grey`, images by :func:`~prismstereo.io.to_grey`: bit for bit what
            :class:`~prismstereo.stream.DepthStream` makes of the decoded frame or the image).
        decode_threads: a video file's decoding threads (>= 1; None: OpenCV's default, about one per core). Where
            the depth graph runs beside the reader on the same cores (``prismstereo depth``), the decoder's extra
            threads preempt the graph's.

    Yields:
        Frame(index, image (C, H, W) float32 in [0, 1], name).

    Raises:
        VideoError: a missing, unopenable or empty source, bad selection, or a frame that cannot be decoded.

    Example:
        >>> [f.index for f in read_frames("frames/", every=2, stop=5)]  # doctest: +SKIP
        [0, 2, 4]
    """
    check_selection(every, start, stop)
    if not isinstance(grey, bool):
        raise VideoError(f"grey must be a bool, got {grey!r}")
    try:
        check_int(decode_threads, "decode_threads", 1, none=True)
    except OptionError as exc:
        raise VideoError(str(exc)) from exc
    text = str(source)
    wanted = (lambda i: i >= start and (i - start) % every == 0)
    if is_video_file(text):
        path = Path(text)
        capture = open_video(path, decode_threads)
        try:
            index = 0
            while stop is None or index < stop:
                ok = capture.grab()
                if not ok:
                    break
                if wanted(index):
                    ok, bgr = capture.retrieve()
                    if not ok or bgr is None:
                        raise VideoError(f"cannot decode frame {index} of {path}")
                    yield Frame(index, frame_to_grey(bgr) if grey else frame_to_tensor(bgr), path.stem)
                index += 1
            if index == 0:
                raise VideoError(f"no frames could be read from {path}")
        finally:
            capture.release()
        return
    files = sequence_files(text)
    for index, file in enumerate(files[: stop if stop is not None else len(files)]):
        if not wanted(index):
            continue
        try:
            image = read_image(file)
        except ImageIOError as exc:
            raise VideoError(f"cannot read frame {index}: {exc}") from exc
        yield Frame(index, to_grey(image) if grey else image, file.name)
