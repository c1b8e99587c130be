"""Where frames come from, without torch: video files (by suffix), directories and glob patterns of images, their
names, files and lengths, and frame selections. :mod:`prismstereo.stream.video` decodes the frames; the jobs plan
their outputs from these (:mod:`prismstereo.jobs.plan`).
"""

from __future__ import annotations

import glob
from pathlib import Path

import cv2

from prismstereo.errors import PrismStereoError

__all__ = ["IMAGE_SUFFIXES", "VIDEO_SUFFIXES", "VideoError", "check_selection", "is_sequence_source", "is_video_file",
           "open_video", "sequence_files", "sequence_length", "sequence_name"]

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
