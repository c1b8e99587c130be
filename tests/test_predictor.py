"""One predictor for both runtimes (:class:`prismstereo.predictor.Predictor`): the same calls on a torch model and on
its exported graphs, the temporal band's calls, the cache behind the ONNX backend, pickling for worker processes,
and its errors."""

import pickle

import pytest
import torch

from prismstereo import OptionError, ShapeError, thesis_setup1
from prismstereo.classical import TemporalOptions
from prismstereo.conventions import to_grey
from prismstereo.models import ModelSpec, build_model
from prismstereo.predictor import Predictor

pytestmark = pytest.mark.usefixtures("one_thread")

RIG = thesis_setup1().downscaled(8)  # 128 x 96
Z = (400.0, 700.0)


@pytest.fixture(scope="module")
def model():
    return build_model(RIG, "classical", Z, {"coarse_factor": 2})


@pytest.fixture(scope="module")
def image():
    from prismstereo.synthetic import ImageFormation, render, slanted_plane

    return render(RIG, slanted_plane(RIG, 550.0, 20.0, seed=2), ImageFormation(supersample=2, noise_sigma=1 / 255,
                                                                                  channels=3)).image


def test_torch_and_onnx_predictors_answer_the_same_calls_alike(model, image, onnx_cache):
    """depth of a batch (colour: its grey, in both runtimes), track around a key frame's prior and the next prior;
    the ONNX predictor's graphs are the cache's, and its rig, range and band options are the model's."""
    options = TemporalOptions(band=2)
    eager = Predictor(model, temporal=options)
    graphs = Predictor(model, backend="onnx", temporal=options)
    assert (eager.backend, graphs.backend) == ("torch", "onnx") and graphs.graph.path.parent == onnx_cache / "onnx"
    assert eager.rig == graphs.rig == RIG and eager.z_range == graphs.z_range == Z
    assert eager.temporal == graphs.temporal and eager.temporal.downsample == 1  # resolved
    assert eager.prior_size == graphs.prior_size == (RIG.image_height, RIG.reference_width)
    assert eager.channels is None and graphs.channels == 1
    a, b = eager.depth(image), graphs.depth(image)
    assert torch.equal(a.depth, eager.depth(to_grey(image)).depth)  # the grey rule, in torch and in the graph
    assert torch.equal(b.depth, graphs.depth(to_grey(image)).depth)
    assert (a.valid == b.valid).float().mean() > 0.999 and a.valid.float().mean() > 0.5
    both = a.valid & b.valid
    torch.testing.assert_close(a.depth[both], b.depth[both], rtol=1e-4, atol=1e-3)
    prior_a, prior_b = eager.band_prior(a), graphs.band_prior(a)
    for x, y in zip(prior_a, prior_b, strict=True):
        assert torch.equal(x, y)  # the key frame's prior is computed in torch either way
    tracked_a, tracked_b = eager.track(image, prior_a), graphs.track(image, prior_b)
    assert (tracked_a.result.valid == tracked_b.result.valid).float().mean() > 0.995
    assert tracked_a.prior.inverse.shape == tracked_b.prior.inverse.shape == (1, 1, *eager.prior_size)
    assert "temporal prior on sequences (a band +-2 around" in eager.summary and graphs.summary == eager.summary


def test_a_spec_is_served_from_the_cache_without_building_the_model(tmp_path, monkeypatch):
    from prismstereo.classical import PrismStereo

    spec = ModelSpec(rig=RIG, kind="classical", z_range=Z, config={"coarse_factor": 2})
    first = Predictor(spec, backend="onnx", temporal=TemporalOptions(), cache_dir=tmp_path)
    assert not first.cached and first.temporal_graph is not None
    monkeypatch.setattr(PrismStereo, "__init__", lambda *a, **k: pytest.fail("a model was built"))
    again = Predictor(spec, backend="onnx", temporal=TemporalOptions(), cache_dir=tmp_path)
    assert again.cached and again.summary == first.summary and again.temporal == first.temporal
    assert again.graph.path == first.graph.path and again.temporal_graph.path == first.temporal_graph.path


def test_a_predictor_pickles_as_what_it_runs_and_opens_its_own_sessions(model, image):
    graphs = Predictor(model, backend="onnx")
    copy = pickle.loads(pickle.dumps(graphs))
    assert copy._graphs._sessions == {} and copy.graph is not graphs.graph  # a process of its own opens its session
    assert torch.equal(copy.depth(image).depth, graphs.depth(image).depth)
    worker = graphs.for_process(1)
    assert worker.threads == 1 and worker.graph.session.get_session_options().intra_op_num_threads == 1
    eager = pickle.loads(pickle.dumps(Predictor(model, threads=1)))
    assert eager.threads == 1 and torch.equal(eager.depth(image).depth, Predictor(model).depth(image).depth)


def test_deployed_graph_files_run_behind_the_same_calls(model, image, export_once):
    # graph files as export_onnx writes them: the session's exports of the model and its band (the graphs the ONNX
    # predictor of test_torch_and_onnx_predictors_answer_the_same_calls_alike runs, exported once for both)
    path = export_once(model)
    band = export_once(model, temporal=TemporalOptions(band=2))
    files = Predictor.from_graphs(path, band, threads=1)
    assert files.temporal is not None and "input (B, 1, 96, 128)" in files.summary
    res = files.depth(image)
    assert res.depth.shape == (1, 1, 96, 64)
    assert files.track(image, files.band_prior(res)).result.depth.shape == (1, 1, 96, 64)
    assert Predictor.from_graphs(path).temporal is None


def test_predictor_errors(model, image, tmp_path):
    with pytest.raises(OptionError, match="Unknown backend 'tensorrt'"):
        Predictor(model, backend="tensorrt")
    with pytest.raises(OptionError, match="threads must be an int >= 1"):
        Predictor(model, threads=0)
    with pytest.raises(OptionError, match="temporal must be None or TemporalOptions"):
        Predictor(model, temporal={"band": 1})
    with pytest.raises(OptionError, match="must be a depth model"):
        Predictor(torch.nn.Identity())
    single = Predictor(build_model(RIG, "classical", Z), temporal=TemporalOptions())  # one level: no band
    assert single.temporal is None and "every frame on its own" in single.summary
    with pytest.raises(OptionError, match="this predictor has no temporal band"):
        single.band_prior(single.depth(image))
    with pytest.raises(OptionError, match="an ONNX predictor has graphs, not a torch model"):
        _ = Predictor(model, backend="onnx").model
    with pytest.raises(OptionError, match="a torch predictor has a model, not graphs"):
        _ = single.graph
    with pytest.raises(ShapeError):
        Predictor(model, backend="onnx").depth(torch.rand(1, 1, 48, 64))
