"""A model's graphs without torch (:class:`prismstereo.export.graphs.GraphPredictor`): the predictor's calls on numpy
arrays, the same bits as the ONNX :class:`~prismstereo.predictor.Predictor` on tensors, its metadata, pickling and
errors."""

import dataclasses
import pickle

import numpy as np
import pytest

from prismstereo import OptionError, ShapeError, thesis_setup1
from prismstereo.classical import TemporalOptions
from prismstereo.export import GraphFiles
from prismstereo.export.graphs import GraphPredictor
from prismstereo.models import build_model
from prismstereo.predictor import Predictor

pytestmark = pytest.mark.usefixtures("one_thread")

RIG = thesis_setup1().downscaled(8)  # 128 x 96
OPTIONS = TemporalOptions(band=2)


@pytest.fixture(scope="module")
def model():
    return build_model(RIG, "classical", (400.0, 700.0), {"coarse_factor": 2})


@pytest.fixture(scope="module")
def graphs(model, export_once):
    return export_once(model), export_once(model, temporal=OPTIONS)


@pytest.fixture(scope="module")
def image():
    from prismstereo.synthetic import ImageFormation, render, slanted_plane

    return render(RIG, slanted_plane(RIG, 550.0, 20.0, seed=2), ImageFormation(supersample=1, noise_sigma=1 / 255,
                                                                                  channels=3)).image


def test_arrays_in_arrays_out_the_bits_of_the_onnx_predictor(graphs, image):
    """depth (colour: its grey), band_prior and track on numpy arrays give the ONNX predictor's tensors bit for bit;
    the metadata gives the sensor, the reference half, the range, the band's options and its prior's size."""
    numpy_side = GraphPredictor(*graphs)
    tensor_side = Predictor.from_graphs(*graphs)
    assert numpy_side.image_size == (RIG.image_height, RIG.image_width) and numpy_side.backend == "onnx"
    assert numpy_side.reference_width == RIG.reference_width and numpy_side.z_range == (400.0, 700.0)
    assert numpy_side.temporal == tensor_side.temporal == dataclasses.replace(OPTIONS, downsample=1)
    assert numpy_side.channels == 1
    assert numpy_side.prior_size == tensor_side.prior_size and not numpy_side.dense and not numpy_side.cached
    got, want = numpy_side.depth(image.numpy()), tensor_side.depth(image)
    for a, b in zip(got, want, strict=True):
        assert isinstance(a, np.ndarray) and np.array_equal(a, b.numpy())
    grey = GraphPredictor(*graphs).depth(numpy_side.graph._image(image[:, :1]))  # one channel in: as is
    assert grey.depth.shape == got.depth.shape
    prior, prior_t = numpy_side.band_prior(got), tensor_side.band_prior(want)
    assert all(np.array_equal(a, b.numpy()) for a, b in zip(prior, prior_t, strict=True))
    tracked, tracked_t = numpy_side.track(image.numpy(), prior), tensor_side.track(image, prior_t)
    assert all(np.array_equal(a, b.numpy()) for a, b in zip(tracked.result, tracked_t.result, strict=True))
    assert all(np.array_equal(a, b.numpy()) for a, b in zip(tracked.prior, tracked_t.prior, strict=True))


def test_cache_entries_pickling_and_errors(graphs, image):
    files = GraphFiles(graphs[0], "a model", graphs[1], cached=True)
    served = GraphPredictor(files, threads=1)
    assert served.summary == "a model" and served.cached and served.graph.threads == 1
    copy = pickle.loads(pickle.dumps(served))
    assert copy._sessions == {} and np.array_equal(copy.depth(image.numpy()).depth, served.depth(image.numpy()).depth)
    assert served.for_process(2).graph.threads == 2 and GraphPredictor(graphs[0]).temporal is None
    assert GraphPredictor(graphs[0]).rig == RIG  # built from the metadata on request (imports torch)
    with pytest.raises(OptionError, match="is a temporal graph: pass it as temporal_graph"):
        GraphPredictor(graphs[1])
    with pytest.raises(OptionError, match="is a per-frame graph, not a temporal one"):
        GraphPredictor(graphs[0], graphs[0])
    with pytest.raises(OptionError, match="the temporal graph of a GraphFiles is its own"):
        GraphPredictor(files, graphs[1])
    with pytest.raises(OptionError, match="no temporal band"):
        GraphPredictor(graphs[0]).band_prior(served.depth(image.numpy()))
    with pytest.raises(ShapeError, match=r"image must have shape \(B, 1, 96, 128\)"):
        served.depth(np.zeros((1, 1, 8, 8), np.float32))
    with pytest.raises(OptionError, match="Unknown arrays 'jax'. Choose from: 'torch', 'numpy'"):
        GraphPredictor(graphs[0], arrays="jax")


def test_a_dense_classical_graph_says_so(export_once):
    from prismstereo.classical import preset

    dense = build_model(RIG, "classical", (400.0, 700.0), preset("dense"))
    assert GraphPredictor(export_once(dense)).dense
