"""Video and image-sequence sources, the stream API (torch and ONNX) and ``prismstereo depth`` on them."""

import dataclasses
import re
import threading

import cv2
import numpy as np
import pytest
import torch
from kornia.color import rgb_to_grayscale

from prismstereo import thesis_setup1
from prismstereo.cli import main
from prismstereo.conventions import to_grey
from prismstereo.errors import OptionError, ShapeError
from prismstereo.io import read_depth, write_image
from prismstereo.predictor import Predictor
from prismstereo.stream import DepthStream
from prismstereo.stream.video import (
    VideoError,
    frame_to_grey,
    frame_to_tensor,
    is_sequence_source,
    read_frames,
    sequence_length,
)
from prismstereo.threads import thread_plan, torch_threads

pytestmark = pytest.mark.usefixtures("one_thread")

DEPTHS = (500.0, 520.0, 540.0, 560.0, 580.0)  # a plane moving away, one depth per frame


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """A rig file, five frames of a receding textured plane as PNGs and as an MJPG .avi (written with OpenCV)."""
    from prismstereo import synthetic as syn

    folder = tmp_path_factory.mktemp("video")
    rig = thesis_setup1().downscaled(8)
    rig.to_json(folder / "small.json")
    scenes = [syn.fronto_parallel_plane(rig, z, seed=3) for z in DEPTHS]
    cap = syn.render(rig, scenes, syn.ImageFormation(supersample=2, noise_sigma=1 / 255, seed=1))
    (folder / "frames").mkdir()
    writer = cv2.VideoWriter(str(folder / "clip.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 5.0,
                             (rig.image_width, rig.image_height))
    assert writer.isOpened()
    for k, image in enumerate(cap.image):
        write_image(folder / "frames" / f"f{k:03d}.png", image, bits=8)
        grey = (image[0].numpy() * 255).round().astype(np.uint8)
        writer.write(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR))
    writer.release()
    return folder


def _depth(*args):
    return main(["depth", *[str(a) for a in args]])


def test_read_frames_of_videos_directories_and_globs(clip):
    assert is_sequence_source(clip / "clip.avi") and is_sequence_source(clip / "frames")
    assert not is_sequence_source(clip / "frames" / "f000.png")
    assert sequence_length(clip / "clip.avi") == 5 and sequence_length(clip / "frames") == 5
    video = list(read_frames(clip / "clip.avi", every=2))
    assert [f.index for f in video] == [0, 2, 4] and video[0].image.shape == (3, 96, 128)
    assert video[0].name == "clip" and video[0].image.dtype == torch.float32
    files = list(read_frames(str(clip / "frames" / "*.png"), start=1, stop=4))
    assert [f.index for f in files] == [1, 2, 3] and files[0].name == "f001.png"
    same = list(read_frames(clip / "frames", start=1, stop=4))
    assert all(torch.equal(a.image, b.image) for a, b in zip(files, same, strict=True))
    # MJPG is lossy: the video's frames are close to the PNGs, not equal
    assert float((video[1].image.mean(0) - list(read_frames(clip / "frames"))[2].image[0]).abs().mean()) < 0.03
    # grey frames: what the stream converts decoded colour frames to (frame_to_grey), bit for bit; kornia's
    # BT.601 grey of the colour frames to float rounding
    grey = list(read_frames(clip / "clip.avi", every=2, grey=True))
    assert [f.index for f in grey] == [0, 2, 4] and grey[0].image.shape == (1, 96, 128)
    for g, f in zip(grey, video, strict=True):
        torch.testing.assert_close(g.image, rgb_to_grayscale(f.image), rtol=0.0, atol=2e-7)
    capture = cv2.VideoCapture(str(clip / "clip.avi"))
    try:
        decoded = capture.read()[1]
    finally:
        capture.release()
    assert torch.equal(grey[0].image, frame_to_grey(decoded))
    png = list(read_frames(clip / "frames", stop=1))[0].image
    assert png.shape[0] == 1 and torch.equal(list(read_frames(clip / "frames", stop=1, grey=True))[0].image, png)


def test_frame_to_tensor_reference_values():
    bgr = np.array([[[0, 128, 255], [10, 20, 30]]], dtype=np.uint8)  # (1, 2, 3) BGR
    rgb = frame_to_tensor(bgr)
    assert rgb.shape == (3, 1, 2) and rgb.is_contiguous() and rgb.dtype == torch.float32
    torch.testing.assert_close(rgb[:, 0, 0], torch.tensor([255.0, 128.0, 0.0]) / 255.0, rtol=0.0, atol=0.0)
    torch.testing.assert_close(rgb[:, 0, 1], torch.tensor([30.0, 20.0, 10.0]) / 255.0, rtol=0.0, atol=0.0)
    assert frame_to_tensor(bgr[..., 0]).shape == (1, 1, 2)
    with pytest.raises(ShapeError, match="uint8"):
        frame_to_tensor(bgr.astype(np.float32))


def test_frame_to_grey_is_the_bt601_grey_of_the_frame():
    bgr = np.array([[[0, 128, 255], [10, 20, 30], [255, 255, 255]]], dtype=np.uint8)  # (1, 3, 3) BGR
    grey = frame_to_grey(bgr)
    assert grey.shape == (1, 1, 3) and grey.dtype == torch.float32
    expected = torch.tensor([0.299 * 255 + 0.587 * 128, 0.299 * 30 + 0.587 * 20 + 0.114 * 10, 255.0]) / 255.0
    torch.testing.assert_close(grey[0, 0], expected, rtol=0.0, atol=2e-7)
    frame = np.random.default_rng(0).integers(0, 256, (40, 50, 3), dtype=np.uint8)
    torch.testing.assert_close(frame_to_grey(frame), to_grey(frame_to_tensor(frame)), rtol=0.0, atol=2e-7)
    assert torch.equal(frame_to_grey(frame[..., 1]), frame_to_tensor(frame[..., 1]))  # grey stays as it is
    with pytest.raises(ShapeError, match="uint8"):
        frame_to_grey(frame.astype(np.float32))
    with pytest.raises(ShapeError, match="BGR"):
        frame_to_grey(frame[..., :2])


def test_read_frames_errors(clip, tmp_path):
    with pytest.raises(VideoError, match="video not found"):
        list(read_frames(tmp_path / "missing.mp4"))
    (tmp_path / "junk.mp4").write_bytes(b"not a video")
    with pytest.raises(VideoError, match="OpenCV cannot open the video|no frames could be read"):
        list(read_frames(tmp_path / "junk.mp4"))
    with pytest.raises(VideoError, match="no images"):
        list(read_frames(tmp_path))
    with pytest.raises(VideoError, match="every must be an int >= 1"):
        list(read_frames(clip / "frames", every=0))
    with pytest.raises(VideoError, match="stop must be an int > start"):
        list(read_frames(clip / "frames", start=3, stop=2))
    with pytest.raises(VideoError, match="grey must be a bool"):
        list(read_frames(clip / "frames", grey="yes"))
    for threads in (0, 1.0, True):
        with pytest.raises(VideoError, match="decode_threads must be an int >= 1 or None"):
            list(read_frames(clip / "clip.avi", decode_threads=threads))
    (tmp_path / "seq").mkdir()
    (tmp_path / "seq" / "a.png").write_bytes(b"broken")
    with pytest.raises(VideoError, match="cannot read frame 0"):
        list(read_frames(tmp_path / "seq"))


def test_read_frames_on_one_decoding_thread_decodes_the_same_frames(clip):
    one = list(read_frames(clip / "clip.avi", decode_threads=1))
    default = list(read_frames(clip / "clip.avi"))
    assert len(one) == len(default) == 5
    assert all(torch.equal(a.image, b.image) for a, b in zip(one, default, strict=True))


def test_stream_torch_and_onnx_agree_and_number_frames(clip, export_once):
    from prismstereo.classical.model import PrismStereo

    rig = thesis_setup1().downscaled(8)
    model = PrismStereo(rig, (400.0, 700.0))
    frames = [f.image for f in read_frames(clip / "frames")]
    torch_stream = DepthStream(model)
    onnx_stream = DepthStream(export_once(model))  # the graph the CLI's --backend onnx runs below
    assert (torch_stream.backend, onnx_stream.backend) == ("torch", "onnx")
    for k, (frame, z) in enumerate(zip(frames, DEPTHS, strict=True)):
        a, b = torch_stream.push(frame), onnx_stream.push(frame)  # RGB -> grey inside
        assert a.frame == b.frame == k and a.depth.shape == (1, 1, 96, 64)
        assert torch.equal(a.valid, b.valid)
        torch.testing.assert_close(a.depth[a.valid], b.depth[b.valid], rtol=1e-4, atol=1e-3)
        assert abs(float(a.depth[a.valid].median()) / z - 1) < 0.01
    bgr = cv2.cvtColor((frames[0][0].numpy() * 255).round().astype(np.uint8), cv2.COLOR_GRAY2BGR)
    assert torch_stream.push(bgr).frame == 5 and len(torch_stream.times_ms) == 6
    assert torch_stream.frames_per_second() > 0


def test_temporal_streams_of_both_backends_agree(clip, export_once):
    from prismstereo.classical.model import PrismStereo
    from prismstereo.classical.prior import TemporalOptions

    model = PrismStereo(thesis_setup1().downscaled(8), (400.0, 700.0), {"coarse_factor": 2})
    options = TemporalOptions(band=2)
    frames = [f.image for f in read_frames(clip / "frames")]
    torch_stream = DepthStream(model, temporal=options)
    per_frame = export_once(model)  # graph files (shared with tests/test_predictor.py: the same model and band)
    band = export_once(model, temporal=options)
    onnx_stream = DepthStream(Predictor.from_graphs(per_frame, band), temporal=True)
    assert torch_stream.temporal == onnx_stream.temporal == dataclasses.replace(options, downsample=1)  # resolved
    # sessions opened from paths: the temporal graph on one intra-op thread (threads.thread_plan)
    predictor = onnx_stream.predictor
    opened = [g.session.get_session_options().intra_op_num_threads for g in (predictor.graph,
                                                                             predictor.temporal_graph)]
    assert opened == [thread_plan().graph, 1]
    for k, (frame, z) in enumerate(zip(frames, DEPTHS, strict=True)):
        a, b = torch_stream.push(frame), onnx_stream.push(frame)
        assert a.keyframe == b.keyframe and (a.keyframe or k > 0)  # 20 mm steps: some frames need the full model
        assert (a.valid == b.valid).float().mean() >= 0.995
        both = a.valid & b.valid
        torch.testing.assert_close(a.depth[both], b.depth[both], rtol=1e-3, atol=1e-2)
        assert abs(float(b.depth[b.valid].median()) / z - 1) < 0.01
    with pytest.raises(OptionError, match="the temporal prior needs a band to place on the previous frame"):
        DepthStream(per_frame, temporal=True)
    with pytest.raises(OptionError, match="is a per-frame graph"):
        Predictor.from_graphs(per_frame, per_frame)
    with pytest.raises(OptionError, match="is a temporal graph: pass it as temporal_graph"):
        Predictor.from_graphs(band)


@pytest.mark.parametrize("backend", ["torch", "onnx"])
def test_hybrid_key_frames_tracked_by_the_classical_band(clip, tmp_path, backend, monkeypatch):
    """A stream whose key frames are the hybrid's and whose tracked frames are the band it offers (the classical
    model's: here one with a band, which the small rig's default lacks): a key frame is the hybrid's result, tracked
    frames follow the plane; the ONNX predictor of the same request runs the two graphs alone; without a band the
    temporal prior is refused."""
    from prismstereo.classical.model import PrismStereo
    from prismstereo.classical.prior import TemporalOptions
    from prismstereo.classical.temporal import TemporalDepth
    from prismstereo.learned import HybridStereo

    rig = thesis_setup1().downscaled(8)
    hybrid = HybridStereo(rig, (400.0, 700.0)).eval()
    with pytest.raises(OptionError, match="the temporal prior needs a band"):
        DepthStream(hybrid, temporal=True)  # the small rig's classical default: one level, no band
    classical = PrismStereo(rig, (400.0, 700.0), {"coarse_factor": 2})
    monkeypatch.setattr(hybrid, "tracker", lambda options=None: TemporalDepth(classical, options))
    options = TemporalOptions(band=2)
    predictor = Predictor(hybrid, backend=backend, temporal=options)
    assert "tracked between key frames by the classical model" in predictor.summary
    stream = DepthStream(predictor, temporal=True)
    frames = [f.image for f in read_frames(clip / "frames")]
    tracked = 0
    for k, (frame, z) in enumerate(zip(frames, DEPTHS, strict=True)):
        res = stream.push(frame)
        if k == 0:
            assert res.keyframe
            with torch.no_grad():
                first = hybrid(frame[None])
            torch.testing.assert_close(res.depth, first.depth, rtol=1e-4, atol=1e-3)
        tracked += not res.keyframe
        assert abs(float(res.depth[res.valid].median()) / z - 1) < 0.01
    assert tracked >= 1 and stream.keyframes >= 1
    if backend == "onnx":  # the hybrid's graph and its band's temporal graph in the cache, run alone
        from prismstereo.export import cache_path

        graph, band = cache_path(hybrid), cache_path(hybrid, temporal=options)
        assert graph.is_file() and band.is_file()
        again = DepthStream(Predictor.from_graphs(graph, band), temporal=True)
        stream = DepthStream(predictor, temporal=True)
        for frame in frames:
            a, b = stream.push(frame), again.push(frame)
            assert a.keyframe == b.keyframe and torch.equal(a.valid, b.valid) and torch.equal(a.depth, b.depth)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("size", [(48, 64), (53, 70), (6, 40)])
def test_stream_cut_thumbnail_is_torch_s(dtype, size):
    """The stream's 8 x 8 block means (OpenCV's area resize) are torch's average pooling to float rounding, whole
    blocks only (an image smaller than a block is its own thumbnail)."""
    from prismstereo.stream.frame_stream import block_means

    g = torch.Generator().manual_seed(3)
    grey = torch.rand(1, 1, *size, generator=g, dtype=dtype)
    thumb = torch.from_numpy(block_means(grey[0, 0].numpy()))
    expected = (grey if min(size) < 8 else torch.nn.functional.avg_pool2d(grey, 8))[0, 0]
    assert thumb.shape == expected.shape and thumb.dtype == dtype
    torch.testing.assert_close(thumb, expected, atol=1e-6, rtol=0)


def test_stream_is_thread_safe_and_checks_its_input():
    from prismstereo.classical.model import PrismStereo

    stream = DepthStream(PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0)))
    numbers: list[int] = []
    gen = torch.Generator().manual_seed(0)
    frames = [torch.rand(1, 48, 64, generator=gen) for _ in range(6)]

    def feed(items):
        numbers.extend(stream.push(f).frame for f in items)

    threads = [threading.Thread(target=feed, args=(frames[i::2],)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(numbers) == list(range(6)) and stream.frames == 6
    with pytest.raises(ShapeError, match="frame is 32x48 px but the model expects 64x48"):
        stream.push(torch.rand(1, 48, 32))
    with pytest.raises(ShapeError, match=r"a frame must be \(C, H, W\) or \(1, C, H, W\)"):
        stream.push(torch.rand(2, 1, 48, 64))
    with pytest.raises(ShapeError, match="frame is 3x64 px"):  # a float array is (C, H, W)
        stream.push(np.zeros((48, 64, 3), np.float32))
    with pytest.raises(OptionError, match="an .onnx file"):
        DepthStream("model.pt")
    with pytest.raises(OptionError, match="a predictor, a depth model or an .onnx file"):
        DepthStream(torch.nn.Identity())


def test_onnx_stream_does_its_tensor_work_on_one_torch_thread(export_once, monkeypatch):
    """An ONNX stream's push runs on one torch intra-op thread and restores the count, also with pushes of two
    streams from two threads at once; a torch stream keeps the caller's threads for its model."""
    import prismstereo.stream.depth_stream as stream_module
    from prismstereo.classical.model import PrismStereo

    model = PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0))
    streams = {"onnx": DepthStream(export_once(model)), "onnx 2": DepthStream(export_once(model)),
               "torch": DepthStream(model)}
    seen: dict[str, set[int]] = {name: set() for name in streams}
    convert = stream_module.frame_to_grey

    def spy(frame):  # the stream's conversion of an OpenCV frame, on the pushing thread
        seen[threading.current_thread().name].add(torch.get_num_threads())
        return convert(frame)

    monkeypatch.setattr(stream_module, "frame_to_grey", spy)
    with torch_threads(2):
        gen = np.random.default_rng(0)
        frames = [gen.integers(0, 256, (48, 64), dtype=np.uint8) for _ in range(4)]  # as OpenCV decodes them
        threads = [threading.Thread(target=lambda s=streams[n]: [s.push(f) for f in frames], name=n)
                   for n in ("onnx", "onnx 2")]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        threading.current_thread().name, main = "torch", threading.current_thread().name
        try:
            streams["torch"].push(frames[0])
        finally:
            threading.current_thread().name = main
        assert seen == {"onnx": {1}, "onnx 2": {1}, "torch": {2}}
        assert torch.get_num_threads() == 2  # restored after the last of the overlapping pushes


@pytest.mark.parametrize("backend", ["torch", "onnx"])
def test_depth_cli_on_a_video_writes_numbered_frames(clip, tmp_path, capsys, monkeypatch, backend):

    import prismstereo.sources

    asked = []
    original = prismstereo.sources.decode_frames

    def spy(*args, **kwargs):
        asked.append(kwargs.get("decode_threads"))
        return original(*args, **kwargs)

    monkeypatch.setattr(prismstereo.sources, "decode_frames", spy)
    out = tmp_path / "out"
    assert _depth(clip / "clip.avi", "--rig", clip / "small.json", "--out", out, "--z-range", 400, 700,
                  "--every", 2, "--backend", backend, "--preview-video", tmp_path / "preview.mp4",
                  "--format", "tiff") == 0
    text = capsys.readouterr().out
    assert "3 depth maps to write from 1 of 1 inputs" in text and "frames/s" in text
    # its first frame read before the model is built, then the frames decoded on every core but the graph's
    assert asked == [None, thread_plan().decode]
    names = sorted(p.name for p in out.iterdir())
    assert names == ["clip_000000.tiff", "clip_000001.tiff", "clip_000002.tiff"]
    for k, z in enumerate(DEPTHS[::2]):
        depth = read_depth(out / f"clip_{k:06d}.tiff").numpy()
        assert abs(np.nanmedian(depth) / z - 1) < 0.02
    preview = cv2.VideoCapture(str(tmp_path / "preview.mp4"))
    assert preview.isOpened() and int(preview.get(cv2.CAP_PROP_FRAME_COUNT)) == 3
    preview.release()


@pytest.mark.parametrize("backend", ["torch", "onnx"])
def test_depth_cli_uses_the_temporal_prior_on_videos_unless_told(clip, tmp_path, capsys, backend):
    common = ["--rig", clip / "small.json", "--z-range", 400, 700, "--downsample", 2, "--full-band", 2,
              "--backend", backend]
    assert _depth(clip / "clip.avi", "--out", tmp_path / "a", *common) == 0
    text = capsys.readouterr().out
    # key frames: the first, then the stream's rules; on this 128 x 96 sensor the tracked band keeps ~2.5 % fewer
    # pixels than the key frame's clamped band, so every other frame's prior exceeds max_invalid_growth (measured
    # 3 of 5; 2 of 20 on the 1024 x 768 moving sequence of benchmarks/video_speed.py)
    assert "temporal prior" in text and re.search(r"\b[1-3] key frames", text), text
    assert _depth(clip / "clip.avi", "--out", tmp_path / "b", *common, "--no-temporal") == 0
    text = capsys.readouterr().out
    assert "temporal prior" not in text and "key frames" not in text
    first = [read_depth(tmp_path / d / "clip_000000.npy") for d in "ab"]
    np.testing.assert_array_equal(first[0].numpy(), first[1].numpy())  # the first frame: the full model
    for k, z in enumerate(DEPTHS):
        depth = read_depth(tmp_path / "a" / f"clip_{k:06d}.npy").numpy()
        assert abs(np.nanmedian(depth) / z - 1) < 0.02


def test_depth_cli_runs_cached_graphs_of_a_video_without_a_torch_model(clip, tmp_path, monkeypatch, capsys):
    """A video's second ONNX run of the same request loads the per-frame and temporal graphs from the cache (no
    torch model built) and writes what the first run wrote. Either way the temporal graph's session has one
    intra-op thread, the per-frame graph's every core (threads.thread_plan)."""
    from prismstereo.export import OnnxDepth

    opened: list[tuple[bool, int]] = []
    original = OnnxDepth.__init__

    def spy(self, path, **kwargs):
        original(self, path, **kwargs)
        opened.append((self.temporal is not None, self.session.get_session_options().intra_op_num_threads))

    monkeypatch.setattr(OnnxDepth, "__init__", spy)
    monkeypatch.setenv("PRISMSTEREO_CACHE", str(tmp_path / "cache"))
    common = ["--rig", clip / "small.json", "--z-range", 400, 700, "--downsample", 2, "--full-band", 2,
              "--backend", "onnx"]
    assert _depth(clip / "clip.avi", "--out", tmp_path / "a", *common) == 0
    assert "(cached graph" not in capsys.readouterr().out
    cores = thread_plan().graph
    assert sorted(set(opened)) == [(False, cores), (True, 1)] and thread_plan().temporal_graph == 1
    from prismstereo.classical.model import PrismStereo

    opened.clear()
    monkeypatch.setattr(PrismStereo, "__init__", lambda *a, **k: pytest.fail("a model was built"))
    assert _depth(clip / "clip.avi", "--out", tmp_path / "b", *common) == 0
    text = capsys.readouterr().out
    assert "(cached graphs), backend onnx" in text and re.search(r"\b[1-3] key frames", text), text
    assert sorted(set(opened)) == [(False, cores), (True, 1)]
    for k in range(len(DEPTHS)):
        name = f"clip_{k:06d}.npy"
        np.testing.assert_array_equal(np.load(tmp_path / "a" / name), np.load(tmp_path / "b" / name))
    # a request without the temporal prior is another request (as a capture's: see tests/cli/test_depth.py)
    monkeypatch.undo()
    monkeypatch.setenv("PRISMSTEREO_CACHE", str(tmp_path / "cache"))
    assert _depth(clip / "clip.avi", "--out", tmp_path / "c", *common, "--no-temporal") == 0
    assert "(cached graph" not in capsys.readouterr().out
    for repeat in range(2):  # so is another binning of the band; then it is served from the cache in turn
        assert _depth(clip / "clip.avi", "--out", tmp_path / f"d{repeat}", *common, "--temporal-binning", 1) == 0
        text = capsys.readouterr().out
        assert ("(cached graphs)" in text) == (repeat == 1), text
        assert "a band +-1 around the previous depth" in text, text  # the full-resolution band, not a binned one
    from prismstereo.classical.prior import TemporalOptions
    from prismstereo.export import OnnxDepth, cache_path
    from prismstereo.geometry.presets import load_rig

    model = PrismStereo(load_rig(clip / "small.json"), (400.0, 700.0), {"downsample": 2, "full_band": 2})
    assert OnnxDepth(cache_path(model, temporal=TemporalOptions(downsample=1))).temporal.downsample == 1


def test_depth_cli_on_a_directory_and_its_errors(clip, tmp_path, capsys):
    out = tmp_path / "seq"
    assert _depth(clip / "frames", "--rig", clip / "small.json", "--out", out, "--z-range", 400, 700,
                  "--start", 3, "--ply") == 0
    # a directory's images keep their names
    assert sorted(p.name for p in out.iterdir()) == ["f003.npy", "f003.ply", "f004.npy", "f004.ply"]
    assert abs(np.nanmedian(np.load(out / "f004.npy")) / DEPTHS[4] - 1) < 0.02
    capsys.readouterr()
    cases = [
        ([clip / "clip.avi", "--out", tmp_path / "d.npy"], "--out must be a directory"),
        ([tmp_path / "none.mp4", "--out", tmp_path / "o"], "video not found"),
        ([clip / "frames", "--out", tmp_path / "o", "--every", 0], "every must be an int >= 1"),
        ([clip / "frames" / "f000.png", "--out", tmp_path / "o", "--every", 2], "need a video, a directory"),
        ([clip / "clip.avi", "--out", tmp_path / "o", "--start", 50], "--start 50 selects no frame"),
        ([clip / "clip.avi", "--out", tmp_path / "o", "--temporal-binning", 0], "--temporal-binning must be >= 1"),
        ([clip / "clip.avi", "--out", tmp_path / "o", "--temporal-binning", 2, "--no-temporal"],
         "--temporal-binning places the temporal prior's band: not with --no-temporal"),
        ([clip / "clip.avi", "--out", tmp_path / "o", "--temporal-binning", 2], "this model has no full-resolution "
         "band for the temporal prior"),  # the small rig's default: one level
        ([clip / "clip.avi", "--out", tmp_path / "o", "--temporal-binning", 64, "--downsample", 2, "--full-band", 2],
         "downsample 64 leaves no level"),
        ([tmp_path / "copy", "--out", tmp_path / "copy", "--format", "npy"], None),
        ([tmp_path / "copy", "--out", tmp_path / "copy", "--format", "png"], "would overwrite the input frame"),
    ]
    import shutil

    shutil.copytree(clip / "frames", tmp_path / "copy")
    for args, message in cases:
        code = _depth(*args, "--rig", clip / "small.json", "--z-range", 400, 700)
        err = capsys.readouterr().err
        if message is None:  # writing next to the frames is fine as long as no frame is overwritten
            assert code == 0
        else:
            assert code == 2 and message in err, err
    (tmp_path / "clash").mkdir()
    write_image(tmp_path / "clash" / "clash_000000.png", torch.rand(1, 96, 128))
    code = _depth(tmp_path / "clash", "--rig", clip / "small.json", "--out", tmp_path / "clash", "--format", "png")
    assert code == 2 and "would overwrite the input frame" in capsys.readouterr().err
