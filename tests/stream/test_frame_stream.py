"""The stream without torch (:class:`prismstereo.stream.frame_stream.FrameStream`): numpy frames through a model's
graphs with the temporal prior, the same key frames and bits as :class:`~prismstereo.stream.DepthStream` on the same
graphs, and its checks."""

import numpy as np
import pytest

from prismstereo import OptionError, ShapeError, thesis_setup1
from prismstereo.classical import TemporalOptions
from prismstereo.export.graphs import GraphPredictor
from prismstereo.models import build_model
from prismstereo.predictor import Predictor
from prismstereo.stream import DepthStream
from prismstereo.stream.frame_stream import FrameStream, block_means

pytestmark = pytest.mark.usefixtures("one_thread")

RIG = thesis_setup1().downscaled(8)
OPTIONS = TemporalOptions(band=2, keyframe_interval=3)


@pytest.fixture(scope="module")
def graphs(export_once):
    model = build_model(RIG, "classical", (400.0, 700.0), {"coarse_factor": 2})
    return export_once(model), export_once(model, temporal=OPTIONS)


@pytest.fixture(scope="module")
def frames():
    """Five frames of a plane moving away as OpenCV's 8-bit BGR arrays, the third one twice."""
    from prismstereo import synthetic as syn

    scenes = [syn.fronto_parallel_plane(RIG, z, seed=3) for z in (500.0, 503.0, 506.0, 509.0, 512.0)]
    cap = syn.render(RIG, scenes, syn.ImageFormation(supersample=1, noise_sigma=1 / 255, seed=1, channels=3))
    bgr = [(image.permute(1, 2, 0).numpy()[..., ::-1] * 255).round().astype(np.uint8) for image in cap.image]
    return bgr[:3] + bgr[2:]


def test_numpy_frames_track_as_the_tensor_stream_does(graphs, frames):
    """Key frames (the first, every keyframe_interval-th) and every result as DepthStream's on the same graphs."""
    plain = FrameStream(GraphPredictor(*graphs), temporal=True)
    tensors = DepthStream(Predictor.from_graphs(*graphs), temporal=True)
    for frame in frames:
        a, b = plain.push(frame), tensors.push(frame)
        assert (a.frame, a.keyframe) == (b.frame, b.keyframe) and isinstance(a.depth, np.ndarray)
        for x, y in zip(a[:3], b[:3], strict=True):
            np.testing.assert_array_equal(x, y.numpy())
    assert plain.keyframes == tensors.keyframes == 2 and plain.frames == 6 and plain.frames_per_second() > 0
    plain.reset()
    assert plain.push(frames[3]).keyframe
    grey = FrameStream(GraphPredictor(*graphs)).push(frames[0].mean(axis=2, dtype=np.float32)[None] / 255)
    assert grey.depth.shape == (1, 1, RIG.image_height, RIG.reference_width) and grey.keyframe


def test_frame_checks_and_options(graphs, frames):
    stream = FrameStream(GraphPredictor(graphs[0]))
    with pytest.raises(ShapeError, match="frame is 64x96 px but the model expects 128x96"):
        stream.push(frames[0][:, :64])
    with pytest.raises(ShapeError, match="a frame must be a numpy array"):
        stream.push([[0.0]])
    with pytest.raises(ShapeError, match=r"a frame must be a \(C, H, W\) or \(1, C, H, W\) float array"):
        stream.push(np.zeros((2, 1, 96, 128), np.float32))
    with pytest.raises(ShapeError, match="frame has 2 channels, the model takes 1"):
        stream.push(np.zeros((2, 96, 128), np.float32))
    with pytest.raises(OptionError, match="the temporal prior needs a band"):
        FrameStream(GraphPredictor(graphs[0]), temporal=True)
    with pytest.raises(OptionError, match="temporal must be a bool or TemporalOptions"):
        FrameStream(GraphPredictor(graphs[0]), temporal="yes")
    rules = FrameStream(GraphPredictor(*graphs), temporal=TemporalOptions(keyframe_interval=7, band=5))
    assert rules.temporal.keyframe_interval == 7 and rules.temporal.band == OPTIONS.band  # the band's own


def test_block_means_reference_values():
    image = np.arange(16 * 24, dtype=np.float32).reshape(16, 24)
    means = block_means(image)
    assert means.shape == (2, 3) and means[0, 0] == image[:8, :8].mean() and means[1, 2] == image[8:, 16:].mean()
    small = np.ones((6, 40), np.float32)
    assert block_means(small) is small
