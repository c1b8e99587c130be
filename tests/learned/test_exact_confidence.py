"""The exact chain's confidence head: its features, the CNN, the hybrid that uses it and what it changes."""

import pytest
import torch

from prismstereo import thesis_setup1
from prismstereo.errors import ShapeError
from prismstereo.learned import HYBRID_WEIGHTS, HybridStereo
from prismstereo.learned.exact_confidence import FEATURES, ConfidenceHead, exact_features
from prismstereo.learned.exact_stage import ExactEvidence
from prismstereo.learned.hybrid import load_hybrid_weights
from prismstereo.synthetic import ImageFormation, render

pytestmark = pytest.mark.usefixtures("one_thread")

Z = (450.0, 1000.0)


def _evidence(h: int = 6, w: int = 5, dtype: torch.dtype = torch.float32) -> ExactEvidence:
    gen = torch.Generator().manual_seed(0)
    maps = [torch.rand(2, 1, h, w, generator=gen, dtype=dtype) for _ in range(5)]
    return ExactEvidence(*maps)


def test_features_are_the_documented_maps_clipped():
    evidence = _evidence()
    evidence = evidence._replace(move=evidence.move * 10, s=torch.zeros_like(evidence.s))
    logit = torch.linspace(-30, 30, 60).view(2, 1, 6, 5)
    out = exact_features(evidence, logit, step=0.01)
    assert out.shape == (2, len(FEATURES), 6, 5) and FEATURES[0] == "logit"
    assert torch.equal(out[:, 0:1], logit.clamp(-10, 10))
    assert torch.equal(out[:, 1:2], evidence.similarity) and torch.equal(out[:, 2:3], evidence.taken)
    assert torch.equal(out[:, 3:4], evidence.move.clamp(max=3))
    assert float(out[:, 4:5].max()) < 1e-3  # a flat s has no spread (the root's floor: 1e-6 / step)
    # the texture: 20 x the grey std over 5 x 5; a reference of alternating 0 / 1 columns: std ~0.5, clipped at 3
    stripes = (torch.arange(5) % 2).to(logit.dtype).expand(2, 1, 6, 5)
    textured = exact_features(evidence._replace(reference=stripes), logit, 0.01)[:, 5:6]
    assert torch.equal(textured, torch.full_like(logit, 3.0))
    flat = exact_features(evidence._replace(reference=torch.full_like(stripes, 0.4)), logit, 0.01)[:, 5:6]
    assert float(flat.abs().max()) < 1e-2  # (float32 rounding of E[x^2] - E[x]^2)
    # a spread in steps: s = 0 / 1 step in alternate columns has a spread of about half a step
    steps = exact_features(evidence._replace(s=stripes * 0.01), logit, 0.01)[:, 4:5]
    assert 0.4 < float(steps[..., 2:4, 1:4].mean()) < 0.6


def test_feature_and_head_shape_errors():
    evidence = _evidence()
    with pytest.raises(ShapeError, match=r"evidence.taken \(2, 1, 3, 5\) must have the logit's shape \(2, 1, 6, 5\)"):
        exact_features(evidence._replace(taken=evidence.taken[..., :3, :]), torch.zeros(2, 1, 6, 5), 0.01)
    with pytest.raises(ShapeError, match="logit must have shape"):
        exact_features(evidence, torch.zeros(2, 6, 5), 0.01)
    with pytest.raises(ShapeError, match=r"features must have shape \(B, 6, H, W\)"):
        ConfidenceHead()(torch.zeros(1, 5, 4, 4))


def test_head_adds_to_the_learned_logit_and_is_differentiable():
    torch.manual_seed(0)
    head = ConfidenceHead()
    x = torch.randn(2, len(FEATURES), 7, 6)
    assert head(x).shape == (2, 1, 7, 6)
    for p in head.out.parameters():
        torch.nn.init.zeros_(p)
    assert torch.equal(head(x), x[:, :1])  # an output layer of zeros keeps the learned confidence
    head = ConfidenceHead(channels=4).double()
    assert torch.autograd.gradcheck(head, (torch.randn(1, len(FEATURES), 5, 5, dtype=torch.float64,
                                                       requires_grad=True),))


def test_a_head_that_does_not_fit_is_refused(tmp_path):
    from prismstereo.learned import WeightsError
    from prismstereo.learned.exact_confidence import load_head

    state = {f"head.{k}": v for k, v in ConfidenceHead(channels=4).state_dict().items()}
    assert load_head({"half.x": torch.zeros(1)}) is None and load_head(state).first.out_channels == 4
    state["head.hidden.weight"] = torch.zeros(4, 4, 3, 3)  # a 3 x 3 convolution where the MLP has 1 x 1
    with pytest.raises(WeightsError, match="the confidence head's weights do not fit ConfidenceHead"):
        load_head(state)
    del state["head.first.weight"]
    with pytest.raises(WeightsError, match="first.weight"):
        load_head(state)


def test_shipped_weights_hold_a_calibrated_head():
    _, state, metadata = load_hybrid_weights(HYBRID_WEIGHTS)
    assert any(k.startswith("head.") for k in state)
    assert 0.5 < metadata["exact_valid_confidence"] < 1.0 and 0.5 < metadata["valid_confidence"] < 1.0
    bad = metadata["head_calibration_bad"]  # the same share of the calibrating pixels kept, fewer of them wrong
    assert bad["head"] < bad["learned"]
    rig = thesis_setup1().downscaled(2)
    exact, learned = (HybridStereo(rig, Z, last_stage=last) for last in ("exact", "learned"))
    assert exact.rescored and exact.valid_confidence == metadata["exact_valid_confidence"]
    assert "re-scoring the confidence" in exact.summary()
    assert not learned.rescored and learned.valid_confidence == metadata["valid_confidence"]
    assert learned.head is not None and "head.out.bias" in learned.weights()  # kept, so that save() keeps it
    untrained = HybridStereo(rig, Z, weights=None)
    assert untrained.head is None and not untrained.rescored


def test_saved_weights_keep_the_head(tmp_path):
    rig = thesis_setup1().downscaled(4)
    model = HybridStereo(rig, Z)
    path = model.save(tmp_path / "w.pt")
    again = HybridStereo(rig, Z, weights=path)
    assert again.rescored and again.describe()["weights_sha256"] == model.describe()["weights_sha256"]
    for (name, a), b in zip(model.weights().items(), again.weights().values(), strict=True):
        assert torch.equal(a, b), name


def test_the_head_ranks_depths_better_than_the_learned_confidence(photo="gravel", seed=105):
    """A photograph as a surface with depth jumps (training's kind of scene, not its captures), 512 x 384: the share of
    the co-visible pixels a threshold keeps at <= 3 % wrong is larger with the head; the depths are the same."""
    from prismstereo.learned.hybrid_data import photo_scene, photographs
    from prismstereo.matching.confidence import confidence_threshold

    rig = thesis_setup1().downscaled(2)
    scene = photo_scene(photographs((photo,))[0], torch.Generator().manual_seed(seed), Z)
    capture = render(rig, scene, ImageFormation(supersample=1, noise_sigma=1 / 255))
    model = HybridStereo(rig, Z).eval()
    with torch.inference_mode():
        rescored = model(capture.image)
        model.head = None
        learned = model(capture.image)
    w = rig.reference_width
    seen = capture.covisible[..., :w] & torch.isfinite(capture.depth[..., :w])
    assert torch.equal(rescored.depth, learned.depth)  # the head changes the confidence only
    right = ((rescored.depth - capture.depth[..., :w]).abs() <= 0.01 * capture.depth[..., :w])[seen]
    kept = {name: confidence_threshold(r.confidence[seen], right, 0.03).kept / int(seen.sum())
            for name, r in (("learned", learned), ("head", rescored))}
    assert kept["head"] > kept["learned"] + 0.01, kept
