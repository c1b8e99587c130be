"""Where frames come from, without torch: video files (by suffix), directories and glob patterns of images, their
names, files and lengths, frame selections, and the frames themselves as numpy arrays (:func:`decode_frames`).
:mod:`prismstereo.stream.video` gives the same frames as tensors; the jobs plan their outputs from these
(:mod:`prismstereo.jobs.plan`).
"""

from __future__ import annotations

import glob
from collections.abc import Iterator
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np

from prismstereo.errors import OptionError, PrismStereoError, ShapeError, check_int

__all__ = ["IMAGE_SUFFIXES", "VIDEO_SUFFIXES", "Frame", "VideoError", "bgr_to_grey", "bgr_to_rgb", "check_selection",
           "decode_frames", "is_sequence_source", "is_video_file", "open_video", "sequence_files", "sequence_length",
           "sequence_name"]

VIDEO_SUFFIXES: tuple[str, ...] = (".mp4", ".avi", ".mkv", ".mov", ".m4v", ".mpg", ".mpeg", ".wmv", ".webm")
IMAGE_SUFFIXES: tuple[str, ...] = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp", ".pgm", ".ppm")


class VideoError(PrismStereoError, OSError):
    """A video or image sequence that cannot be opened or read."""


def _is_glob(text: str) -> bool:
    return any(c in text for c in "*?[")


def is_sequence_source(path: str | Path) -> bool:
    """True for a video file (by suffix), a directory or a glob pattern: what :func:`read_frames` reads.

    Example:
        >>> is_sequence_source("clip.mp4"), is_sequence_source("frames/*.png"), is_sequence_source("a.png")
        (True, True, False)
    """
    text = str(path)
    return is_video_file(text) or _is_glob(text) or Path(text).is_dir()


def is_video_file(path: str | Path) -> bool:
    """True for a video file by its suffix (:data:`VIDEO_SUFFIXES`), not a glob pattern.

    Example:
        >>> is_video_file("clip.MP4"), is_video_file("frames/*.mp4")
        (True, False)
    """
    return Path(str(path)).suffix.lower() in VIDEO_SUFFIXES and not _is_glob(str(path))


def sequence_name(source: str | Path) -> str:
    """A name for the frames of a source: a video's stem, a directory's name, a glob's folder name.

    Example:
        >>> sequence_name("data/clip.mp4"), sequence_name("data/run1/*.png")
        ('clip', 'run1')
    """
    text = str(source)
    path = Path(text)
    if _is_glob(text):
        return path.parent.name or "frames"
    return path.name if path.is_dir() else path.stem


def sequence_files(source: str | Path) -> list[Path]:
    """The image files of a directory (sorted by name) or a glob pattern.

    Raises:
        VideoError: no image files there.

    Example:
        >>> sequence_files("frames/*.png")  # doctest: +SKIP
        [PosixPath('frames/000.png'), PosixPath('frames/001.png')]
    """
    source = str(source)
    if _is_glob(source):
        files = [Path(p) for p in sorted(glob.glob(source))]
    else:
        files = sorted(p for p in Path(source).iterdir())
    files = [p for p in files if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES]
    if not files:
        raise VideoError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in {source}")
    return files


def open_video(path: Path, threads: int | None = None) -> cv2.VideoCapture:
    """An opened OpenCV capture of the video file ``path`` (its decoder on ``threads`` threads; None: OpenCV's
    default).

    Raises:
        VideoError: a missing file, or one OpenCV cannot open.

    Example:
        >>> open_video(Path("missing.mp4"))
        Traceback (most recent call last):
        ...
        prismstereo.sources.VideoError: video not found: missing.mp4
    """
    if not path.is_file():
        raise VideoError(f"video not found: {path}")
    # the decoder's threads are set as the capture opens (setting them afterwards has no effect)
    capture = cv2.VideoCapture(str(path)) if threads is None else cv2.VideoCapture(
        str(path), cv2.CAP_ANY, [cv2.CAP_PROP_N_THREADS, threads])
    if not capture.isOpened():
        raise VideoError(f"OpenCV cannot open the video {path}")
    return capture


def sequence_length(source: str | Path) -> int:
    """Number of frames of a source (a video's container count, which some codecs only estimate).

    Raises:
        VideoError: a missing or unreadable source.

    Example:
        >>> sequence_length("clip.mp4")  # doctest: +SKIP
        120
    """
    text = str(source)
    if is_video_file(text):
        capture = open_video(Path(text))
        try:
            return int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        finally:
            capture.release()
    return len(sequence_files(text))


def check_selection(every: int, start: int, stop: int | None) -> None:
    """Check a frame selection (``every`` >= 1, ``start`` >= 0, ``stop`` > ``start`` or None).

    Raises:
        VideoError: a bad selection.

    Example:
        >>> check_selection(2, 0, None)
    """
    if not isinstance(every, int) or every < 1:
        raise VideoError(f"every must be an int >= 1, got {every!r}")
    if not isinstance(start, int) or start < 0:
        raise VideoError(f"start must be an int >= 0, got {start!r}")
    if stop is not None and (not isinstance(stop, int) or stop <= start):
        raise VideoError(f"stop must be an int > start ({start}) or None, got {stop!r}")


class Frame(NamedTuple):
    """One frame of a source.

    Attributes:
        index: position in the source (0-based; before ``every`` / ``start`` selection).
        image: (C, H, W) float32 in [0, 1], RGB or grey: a numpy array (:func:`decode_frames`) or a tensor
            (:func:`~prismstereo.stream.video.read_frames`).
        name: the image file's name for sequences, ``"<video stem>"`` for videos.
    """

    index: int
    image: Any
    name: str


def _check_frame(bgr: np.ndarray) -> None:
    if not isinstance(bgr, np.ndarray) or bgr.dtype != np.uint8 or bgr.ndim not in (2, 3) or (
            bgr.ndim == 3 and bgr.shape[2] != 3):
        got = f"{bgr.dtype} {bgr.shape}" if isinstance(bgr, np.ndarray) else type(bgr).__name__
        raise ShapeError(f"a decoded frame must be OpenCV's uint8 (H, W) or (H, W, 3) BGR, got {got}")


def bgr_to_rgb(bgr: np.ndarray) -> np.ndarray:
    """A decoded 8-bit frame, OpenCV's uint8 (H, W) or (H, W, 3) BGR, as a (C, H, W) float32 RGB array in [0, 1].

    Raises:
        ShapeError: not such an array.

    Example:
        >>> bgr_to_rgb(np.zeros((4, 5, 3), np.uint8)).shape
        (3, 4, 5)
    """
    _check_frame(bgr)
    if bgr.ndim == 2:
        return (bgr.astype(np.float32) / np.float32(255.0))[None]
    # channel order and layout on the bytes (a quarter of the memory of floats), then one conversion to float
    planes = np.ascontiguousarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB).transpose(2, 0, 1))
    return planes.astype(np.float32) / np.float32(255.0)


# BT.601 luma weights in OpenCV's BGR order, with the 8-bit scale folded in (to_grey's weights, kornia's)
_BGR_LUMA = (np.array([[0.114, 0.587, 0.299]], dtype=np.float64) / 255.0).astype(np.float32)


def bgr_to_grey(frame: np.ndarray) -> np.ndarray:
    """A decoded 8-bit frame, OpenCV's uint8 (H, W) or (H, W, 3) BGR, as the (1, H, W) float32 grey array in [0, 1]
    that a one-channel model takes: :func:`~prismstereo.conventions.to_grey` of :func:`bgr_to_rgb` (BT.601 weights
    0.299, 0.587, 0.114) to float rounding (at most 2e-7), in one pass over the frame instead of one per step.

    Raises:
        ShapeError: not such an array.

    Example:
        >>> bgr_to_grey(np.full((2, 3, 3), 255, np.uint8)).shape
        (1, 2, 3)
    """
    if not isinstance(frame, np.ndarray) or frame.ndim != 3:  # grey (or not a frame: its error)
        return bgr_to_rgb(frame)
    _check_frame(frame)
    # cv2.transform: each pixel's weighted channel sum, one pass over the float frame (the weights carry the 1 / 255)
    return cv2.transform(frame.astype(np.float32), _BGR_LUMA).reshape(frame.shape[:2])[None]


def decode_frames(source: str | Path, *, every: int = 1, start: int = 0, stop: int | None = None,
                  grey: bool = False, decode_threads: int | None = None) -> Iterator[Frame]:
    """The frames ``start``, ``start + every``, ... (< ``stop``) of a video file, directory or glob of images, as
    numpy arrays (what :func:`~prismstereo.stream.video.read_frames` gives as tensors, the same bits).

    Args:
        source: a video file, a directory of images or a glob pattern.
        every: keep one frame in ``every``.
        start: first frame (0-based).
        stop: end (exclusive), None for the whole source.
        grey: frames as (1, H, W) grey, on the thread that reads them: what a one-channel model takes (a video's
            decoded frames by :func:`bgr_to_grey`, images by :func:`~prismstereo.io.grey_array`, bit for bit
            :func:`~prismstereo.conventions.to_grey`).
        decode_threads: a video file's decoding threads (>= 1; None: OpenCV's default, about one per core). Where
            the depth graph runs beside the reader on the same cores (``prismstereo depth``), the decoder's extra
            threads preempt the graph's.

    Yields:
        Frame(index, image (C, H, W) float32 array in [0, 1], name).

    Raises:
        VideoError: a missing, unopenable or empty source, bad selection, or a frame that cannot be decoded.

    Example:
        >>> [f.index for f in decode_frames("frames/", every=2, stop=5)]  # doctest: +SKIP
        [0, 2, 4]
    """
    from prismstereo.io import ImageIOError, decode_image, grey_array

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
                if not capture.grab():
                    break
                if wanted(index):
                    ok, bgr = capture.retrieve()
                    if not ok or bgr is None:
                        raise VideoError(f"cannot decode frame {index} of {path}")
                    yield Frame(index, bgr_to_grey(bgr) if grey else bgr_to_rgb(bgr), path.stem)
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
            image = decode_image(file)
        except ImageIOError as exc:
            raise VideoError(f"cannot read frame {index}: {exc}") from exc
        yield Frame(index, grey_array(image) if grey else image, file.name)
