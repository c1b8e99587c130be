"""prismstereo.sources: what a frame source is, its files and length, and frame selections, without torch."""

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from prismstereo.sources import (
    VideoError,
    check_selection,
    is_sequence_source,
    is_video_file,
    open_video,
    sequence_files,
    sequence_length,
    sequence_name,
)


def test_sources_names_files_and_lengths(tmp_path):
    frames = tmp_path / "run1"
    frames.mkdir()
    for name in ("b.png", "a.png"):
        cv2.imwrite(str(frames / name), np.zeros((4, 6), np.uint8))
    (frames / "notes.txt").write_text("not an image")
    assert is_sequence_source(frames) and is_sequence_source(tmp_path / "*.png") and is_sequence_source("c.MP4")
    assert not is_sequence_source(frames / "a.png") and is_video_file("c.mkv") and not is_video_file("x/*.mp4")
    assert [p.name for p in sequence_files(frames)] == ["a.png", "b.png"]  # sorted, images only
    assert [p.name for p in sequence_files(str(frames / "b*.png"))] == ["b.png"]
    assert sequence_length(frames) == 2 and sequence_name(frames) == "run1" and sequence_name("x/clip.avi") == "clip"
    writer = cv2.VideoWriter(str(tmp_path / "clip.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 5.0, (16, 8))
    for _ in range(3):
        writer.write(np.zeros((8, 16, 3), np.uint8))
    writer.release()
    assert sequence_length(tmp_path / "clip.avi") == 3 and open_video(tmp_path / "clip.avi").isOpened()


def test_source_errors():
    with pytest.raises(VideoError, match="no images"):
        sequence_files(Path(__file__).parent / "data" / "*.nothing")
    with pytest.raises(VideoError, match="video not found: missing.mp4"):
        sequence_length("missing.mp4")
    with pytest.raises(VideoError, match="every must be an int >= 1, got 0"):
        check_selection(0, 0, None)
    with pytest.raises(VideoError, match=r"stop must be an int > start \(3\) or None, got 2"):
        check_selection(1, 3, 2)


def test_sources_import_without_torch():
    code = "import sys; import prismstereo.sources, prismstereo.names; print('torch' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip() == (
        "False")
