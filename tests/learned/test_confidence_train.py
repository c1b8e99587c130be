"""The confidence head's trainer: a tiny run on a small rig, its file, its threshold rule and its errors."""

import pytest
import torch

from prismstereo import thesis_setup1
from prismstereo.errors import OptionError
from prismstereo.learned import HYBRID_WEIGHTS, HybridStereo
from prismstereo.learned.confidence_train import head_inputs, train_exact_confidence
from prismstereo.learned.exact_confidence import FEATURES
from prismstereo.learned.hybrid import load_hybrid_weights
from prismstereo.learned.hybrid_data import render_set

pytestmark = pytest.mark.usefixtures("one_thread")

Z = (450.0, 1000.0)


def test_a_tiny_run_writes_the_weights_with_a_calibrated_head(tmp_path):
    rig = thesis_setup1().downscaled(4)
    variants = [("tiny", rig, Z)]
    out = tmp_path / "hybrid.pt"
    result = train_exact_confidence(HYBRID_WEIGHTS, out, steps=4, seed=3, batch_size=2, crop=32, captures=2,
                                    cache=tmp_path, variants=variants, progress=False)
    assert result.path == out and result.losses.shape == (4,) and bool(torch.isfinite(result.losses).all())
    _, state, metadata = load_hybrid_weights(out)
    _, shipped, _ = load_hybrid_weights(HYBRID_WEIGHTS)
    for name, tensor in shipped.items():  # the refinement as it was, the head replaced
        if not name.startswith("head."):
            assert torch.equal(state[name], tensor), name
    assert any(not torch.equal(state[k], shipped[k]) for k in state if k.startswith("head."))
    assert (metadata["head_steps"], metadata["head_seed"]) == (4, 3)
    model = HybridStereo(rig, Z, weights=out)
    assert model.rescored and model.valid_confidence == metadata["exact_valid_confidence"]
    # the threshold keeps as many of the calibrating capture's known pixels as the learned one did
    data = render_set("tiny", rig, Z, 2, seed=300, cache=tmp_path, binning=model.binning)
    features, right = head_inputs(model, data.grey[1:2].float(), data.truth[1:2], data.known[1:2])
    assert features.shape[1] == len(FEATURES) and right.dtype == torch.bool
    known = data.known[1:2]
    with torch.no_grad():
        head = torch.sigmoid(model.head(features))[known]
    learned = torch.sigmoid(features[:, :1])[known]
    counts = int((head >= model.valid_confidence).sum()), int((learned >= metadata["valid_confidence"]).sum())
    assert abs(counts[0] - counts[1]) <= 0.001 * counts[1], counts  # (the stored threshold is rounded)


def test_trainer_errors(tmp_path):
    for name, value in (("steps", 0), ("captures", 1), ("crop", 4), ("batch_size", 0)):
        with pytest.raises(OptionError, match=name):
            train_exact_confidence(HYBRID_WEIGHTS, tmp_path / "w.pt", **{name: value})
    rig = thesis_setup1().downscaled(4)
    learned = HybridStereo(rig, Z, last_stage="learned")
    grey = torch.rand(1, 1, rig.image_height, rig.image_width)
    with pytest.raises(OptionError, match="last_stage='exact'"):
        head_inputs(learned, grey, torch.zeros(1, 1, 1, 1), torch.zeros(1, 1, 1, 1, dtype=torch.bool))
    assert not list(tmp_path.iterdir())
