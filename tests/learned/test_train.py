"""Training data and the trainer (seeded, the loss falls)."""

import pytest
import torch

from prismstereo import thesis_setup1
from prismstereo.errors import OptionError
from prismstereo.learned import KINDS, LearnedStereo, load_weights, random_capture_spec, train, training_set
from prismstereo.learned.train import depth_loss

pytestmark = pytest.mark.usefixtures("one_thread")

Z_RANGE = (450.0, 1000.0)


@pytest.fixture(scope="module")
def rig():
    return thesis_setup1().downscaled(8)


@pytest.fixture(scope="module")
def data(rig, tmp_path_factory):
    return training_set(rig, 5, seed=1, z_range_mm=Z_RANGE, cache=tmp_path_factory.mktemp("cache"))


def test_training_set(rig, data, tmp_path_factory):
    assert data.image.shape == (5, 1, 96, 128) and data.depth.shape == (5, 1, 96, rig.reference_width)
    assert data.image.dtype == torch.float32 and data.covisible.dtype == torch.bool
    assert [name.split("_")[0] for name in data.names] == list(KINDS)
    depth = data.depth[data.covisible]
    assert depth.min() >= Z_RANGE[0] and depth.max() <= Z_RANGE[1]
    assert data.covisible.float().mean() > 0.5


def test_training_set_is_seeded_and_cached(rig, data, tmp_path):
    again = training_set(rig, 5, seed=1, z_range_mm=Z_RANGE, cache=tmp_path)
    assert torch.equal(again.image, data.image)
    assert len(list(tmp_path.glob("train_128x96_5_1_*.pt"))) == 1
    assert torch.equal(training_set(rig, 5, seed=1, z_range_mm=Z_RANGE, cache=tmp_path).image, data.image)


def test_data_errors(rig):
    with pytest.raises(OptionError, match="Choose from"):
        random_capture_spec(rig, torch.Generator(), Z_RANGE, "cube")
    with pytest.raises(OptionError, match="count"):
        training_set(rig, 0)
    with pytest.raises(OptionError, match="increasing"):
        training_set(rig, 1, z_range_mm=(900.0, 400.0))


def test_training_lowers_the_loss_and_is_seeded(rig, data, tmp_path):
    kwargs = dict(steps=12, batch_size=2, num_hypotheses=12, downscale=1, data=data, learning_rate=3e-3,
                  progress=False)
    result = train(rig, tmp_path / "a.pt", **kwargs)
    assert result.losses.shape == (12,) and result.path.is_file() and result.seconds > 0
    again = train(rig, tmp_path / "b.pt", **kwargs)
    torch.testing.assert_close(again.losses, result.losses)

    def loss(weights):
        torch.manual_seed(0)  # the seed train() initialises with
        model = LearnedStereo(rig, Z_RANGE, num_hypotheses=12, weights=weights, with_match=False)
        with torch.no_grad():
            return float(depth_loss(model, data.image, data.depth, data.covisible))

    before, after = loss(None), loss(result.path)
    assert after < 0.8 * before, (before, after)
    assert load_weights(result.path)[2]["steps"] == 12


def test_train_errors(rig, data, tmp_path):
    with pytest.raises(OptionError, match="steps"):
        train(rig, tmp_path / "w.pt", steps=0, data=data)
    with pytest.raises(OptionError, match="data captures"):
        train(rig, tmp_path / "w.pt", steps=1, data=data, downscale=2)
