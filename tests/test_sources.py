"""prismstereo.sources: what a frame source is, its files and length, frame selections, and frames as numpy arrays,
without torch."""

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from prismstereo.errors import ShapeError
from prismstereo.sources import (
    VideoError,
    bgr_to_grey,
    bgr_to_rgb,
    check_selection,
    decode_frames,
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


def test_decoded_frames_are_the_tensor_readers_bits(tmp_path):
    """decode_frames (numpy) gives read_frames' (tensor) frames bit for bit, grey or colour, from a video and from
    images; bgr_to_rgb / bgr_to_grey are frame_to_tensor / frame_to_grey."""
    torch = pytest.importorskip("torch")
    from prismstereo.stream.video import frame_to_grey, frame_to_tensor, read_frames

    rng = np.random.default_rng(0)
    video = cv2.VideoWriter(str(tmp_path / "v.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 5.0, (32, 24))
    for k in range(3):
        frame = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
        video.write(frame)
        cv2.imwrite(str(tmp_path / f"f{k}.png"), frame)
    video.release()
    for source in (tmp_path / "v.avi", tmp_path / "*.png"):
        for grey in (False, True):
            arrays = list(decode_frames(source, every=2, grey=grey))
            tensors = list(read_frames(source, every=2, grey=grey))
            assert [f.index for f in arrays] == [0, 2] and [f.name for f in arrays] == [f.name for f in tensors]
            assert all(isinstance(a.image, np.ndarray) and torch.equal(torch.from_numpy(a.image), t.image)
                       for a, t in zip(arrays, tensors, strict=True))
    frame = rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)
    assert torch.equal(torch.from_numpy(bgr_to_rgb(frame)), frame_to_tensor(frame))
    assert torch.equal(torch.from_numpy(bgr_to_grey(frame)), frame_to_grey(frame))
    assert bgr_to_grey(frame[..., 0]).shape == (1, 5, 7)
    with pytest.raises(ShapeError, match="OpenCV's uint8"):
        bgr_to_rgb(np.zeros((5, 7, 3), np.float32))
    with pytest.raises(VideoError, match="grey must be a bool"):
        next(decode_frames(tmp_path / "v.avi", grey=1))
    with pytest.raises(VideoError, match="decode_threads must be an int >= 1"):
        next(decode_frames(tmp_path / "v.avi", decode_threads=0))
