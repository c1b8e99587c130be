import pytest
import torch

from prismstereo import OptionError, ShapeError
from prismstereo.matching.confidence import (
    CLAMPED_WEIGHTS,
    DEFAULT_WEIGHTS,
    FEATURES,
    SMOOTHED_FEATURES,
    SMOOTHED_WEIGHTS,
    ConfidenceModel,
    confidence_features,
    confidence_threshold,
    fit_confidence,
    local_spread,
    smoothed_features,
)


def _inputs(h=12, w=16, seed=0):
    g = torch.Generator().manual_seed(seed)
    s = torch.rand(1, 1, h, w, generator=g, dtype=torch.float64) * 0.1
    return dict(ncc=torch.rand(1, 1, h, w, generator=g, dtype=torch.float64),
                coarse=torch.rand(1, 1, h, w, generator=g, dtype=torch.float64), s=s, s0=s + 0.01,
                texture=torch.rand(1, 1, h, w, generator=g, dtype=torch.float64) * 0.1, step=0.01,
                rejected=torch.zeros(1, 1, h, w, dtype=torch.bool))


def test_features_shapes_and_reference_values():
    x = _inputs()
    f = confidence_features(**x)
    assert f.shape == (1, len(FEATURES), 12, 16) and f.dtype == torch.float64
    assert torch.equal(f[:, 0:1], x["ncc"]) and torch.equal(f[:, 1:2], x["coarse"])
    assert torch.allclose(f[:, 3], torch.ones_like(f[:, 3]))  # |s - s0| / step
    assert torch.all(f[:, 5] == 0)
    flat = dict(x, s=torch.full_like(x["s"], 0.3), texture=torch.zeros_like(x["texture"]))
    g = confidence_features(**flat)
    assert torch.allclose(g[:, 2], torch.zeros_like(g[:, 2]), atol=1e-6)  # a constant estimate is not rough
    assert torch.allclose(g[:, 4], torch.full_like(g[:, 4], torch.log(torch.tensor(1e-3, dtype=g.dtype))),
                          atol=1e-3)  # no texture: the floor
    far = dict(x, s0=x["s"] + 1.0)
    assert float(confidence_features(**far)[:, 3].max()) == 3.0  # capped


def test_features_errors():
    x = _inputs()
    with pytest.raises(ShapeError, match="ncc must have the shape"):
        confidence_features(**dict(x, ncc=x["ncc"][..., :5]))
    with pytest.raises(ShapeError, match="texture must have the shape"):
        confidence_features(**dict(x, texture=x["texture"][..., :5]))
    with pytest.raises(OptionError, match="step must be > 0"):
        confidence_features(**dict(x, step=0.0))


def test_model_is_monotone_in_the_match_evidence_and_a_probability():
    model = ConfidenceModel()
    f = confidence_features(**_inputs()).float()
    p = model(f)
    assert p.shape == (1, 1, 12, 16) and bool(((p > 0) & (p < 1)).all())
    better = f.clone()
    better[:, 1] += 0.2  # the coarse level agreed more
    better[:, 2] -= 0.5  # a smoother estimate
    assert bool((model(better) > p).all())
    w = DEFAULT_WEIGHTS
    assert w[FEATURES.index("coarse")] > 0 and w[FEATURES.index("roughness")] < 0
    assert w[FEATURES.index("offset")] < 0  # a band far from the coarse placement is less trusted


def test_model_errors():
    with pytest.raises(OptionError, match="weights must be 7 finite numbers"):
        ConfidenceModel([1.0, 2.0])
    with pytest.raises(ShapeError):
        ConfidenceModel()(torch.zeros(1, 3, 4, 4))


def test_fit_recovers_known_weights():
    g = torch.Generator().manual_seed(1)
    x = torch.randn(20000, len(FEATURES), generator=g, dtype=torch.float64)
    true = torch.tensor([1.5, -2.0, 0.5, 0.0, 1.0, -0.5, 0.3], dtype=torch.float64)
    y = torch.rand(20000, generator=g, dtype=torch.float64) < torch.sigmoid(x @ true[:-1] + true[-1])
    w = fit_confidence(x, y)
    assert torch.allclose(w, true, atol=0.1)
    p = ConfidenceModel(w)(x.T.reshape(1, len(FEATURES), 1, -1))
    assert abs(float(p.mean()) - float(y.double().mean())) < 0.01  # calibrated in the mean


def test_fit_with_a_nonnegative_weight():
    g = torch.Generator().manual_seed(3)
    a = torch.randn(20000, generator=g, dtype=torch.float64)
    x = torch.stack([a + 0.3 * torch.randn(20000, generator=g, dtype=torch.float64), a], 1)  # collinear features
    y = torch.rand(20000, generator=g, dtype=torch.float64) < torch.sigmoid(2.0 * a - 0.5 * x[:, 0])
    free = fit_confidence(x, y)
    assert free[0] < -0.2  # the unconstrained fit gives the first feature a negative weight
    w = fit_confidence(x, y, nonnegative=[0])
    assert w[0] == 0.0 and w[1] > 0
    # the constrained maximum: the fit of the second feature alone, and no better likelihood with w[0] = 0.05
    torch.testing.assert_close(w[1:], fit_confidence(x[:, 1:], y), rtol=1e-6, atol=1e-6)

    def loss(weights: torch.Tensor) -> float:
        logit = x @ weights[:-1] + weights[-1]
        return float(torch.nn.functional.binary_cross_entropy_with_logits(logit, y.double()))

    nudged = w.clone()
    nudged[0] = 0.05
    assert loss(w) < loss(nudged) and loss(free) < loss(w)
    assert torch.equal(fit_confidence(x, y, nonnegative=[1]), free)  # an inactive constraint changes nothing


def test_fit_errors():
    x = torch.zeros(10, len(FEATURES))
    with pytest.raises(OptionError, match="both correct and wrong"):
        fit_confidence(x, torch.ones(10, dtype=torch.bool))
    with pytest.raises(ShapeError, match="correct must be"):
        fit_confidence(x, torch.ones(9, dtype=torch.bool))
    with pytest.raises(OptionError, match="nonnegative must hold feature indices"):
        fit_confidence(x, torch.arange(10) % 2 == 0, nonnegative=[len(FEATURES)])


def test_features_and_model_gradcheck():
    x = {k: (v.requires_grad_(True) if isinstance(v, torch.Tensor) and v.dtype == torch.float64 and k in ("ncc", "s")
             else v) for k, v in _inputs(6, 7).items()}
    model = ConfidenceModel().double()
    s0 = x["s"].detach() + 0.013

    def f(ncc, s):
        return model(confidence_features(**dict(x, ncc=ncc, s=s, s0=s0)))

    assert torch.autograd.gradcheck(f, (x["ncc"], x["s"]), eps=1e-6, atol=1e-4)


def test_smoothed_features_and_model():
    g = torch.Generator().manual_seed(2)
    p, agreement, support = (torch.rand(1, 1, 5, 6, generator=g, dtype=torch.float64) for _ in range(3))
    spread = 4 * torch.rand(1, 1, 5, 6, generator=g, dtype=torch.float64)
    f = smoothed_features(p, agreement, support, spread)
    assert f.shape == (1, len(SMOOTHED_FEATURES), 5, 6) and f.dtype == torch.float64
    assert torch.equal(f[:, 0:1], p) and torch.equal(f[:, 1:2], agreement) and torch.equal(f[:, 2:3], support)
    torch.testing.assert_close(f[:, 3:4], torch.log1p(spread))
    model = ConfidenceModel(names=SMOOTHED_FEATURES)
    q = model(f.float())
    assert q.shape == (1, 1, 5, 6) and bool(((q > 0) & (q < 1)).all())
    w = SMOOTHED_WEIGHTS
    assert w[SMOOTHED_FEATURES.index("confidence")] > 0 and w[SMOOTHED_FEATURES.index("agreement")] > 0
    more = smoothed_features(p, (agreement + 0.1).clamp(max=1.0), support, spread)
    assert bool((model(more.float()) >= q).all())  # more agreement around a pixel: more trust
    for weights in (SMOOTHED_WEIGHTS, CLAMPED_WEIGHTS[1]):  # estimates that jump around a pixel: less trust
        jumpy = ConfidenceModel(weights, SMOOTHED_FEATURES)(smoothed_features(p, agreement, support, spread + 2))
        assert bool((jumpy < ConfidenceModel(weights, SMOOTHED_FEATURES)(f)).all())
    reference = torch.sigmoid((f * torch.tensor(w[:-1], dtype=f.dtype).view(1, -1, 1, 1)).sum(1, keepdim=True) + w[-1])
    torch.testing.assert_close(ConfidenceModel(names=SMOOTHED_FEATURES).double()(f), reference, rtol=1e-5, atol=1e-6)
    with pytest.raises(ShapeError, match="support must have the shape"):
        smoothed_features(p, agreement, support[..., :2], spread)
    with pytest.raises(ShapeError, match="spread must have the shape"):
        smoothed_features(p, agreement, support, spread[..., :2])
    with pytest.raises(OptionError, match="names must be FEATURES"):
        ConfidenceModel(names=("ncc",))
    with pytest.raises(OptionError, match="weights must be 5 finite numbers"):
        ConfidenceModel(DEFAULT_WEIGHTS, SMOOTHED_FEATURES)


def test_local_spread():
    g = torch.Generator().manual_seed(3)
    x = torch.rand(2, 1, 9, 11, generator=g, dtype=torch.float64)
    mask = torch.rand(2, 1, 9, 11, generator=g) > 0.3
    out = local_spread(x, mask, 5)
    assert out.shape == x.shape and out.dtype == x.dtype
    # reference: a loop over the boxes (clipped at the image borders)
    ref = torch.zeros_like(x)
    for b in range(2):
        for i in range(9):
            for j in range(11):
                rows, cols = slice(max(0, i - 2), i + 3), slice(max(0, j - 2), j + 3)
                box = x[b, 0, rows, cols][mask[b, 0, rows, cols]]
                ref[b, 0, i, j] = box.max() - box.min() if box.numel() else 0.0
    torch.testing.assert_close(out, ref)
    # a plane's estimates spread by its slope only; a step by its height near the step
    plane = torch.arange(12.0).view(1, 1, 1, 12).expand(1, 1, 6, 12) * 0.1
    torch.testing.assert_close(local_spread(plane, torch.ones_like(plane, dtype=torch.bool), 3)[..., 1:-1],
                               torch.full((1, 1, 6, 10), 0.2))
    step = torch.zeros(1, 1, 4, 8)
    step[..., 4:] = 5.0
    assert local_spread(step, torch.ones_like(step, dtype=torch.bool), 3)[0, 0, 0].tolist() == [0, 0, 0, 5, 5, 0, 0, 0]
    assert float(local_spread(step, torch.zeros_like(step, dtype=torch.bool), 3).abs().max()) == 0.0  # nothing counts
    assert torch.autograd.gradcheck(lambda v: local_spread(v, mask, 3), (x.requires_grad_(),))
    with pytest.raises(ShapeError, match="mask must be a bool tensor"):
        local_spread(x, mask.double(), 3)
    with pytest.raises(ShapeError, match="values must"):
        local_spread(x[0], mask[0], 3)
    with pytest.raises(OptionError, match="window must be a positive odd int"):
        local_spread(x, mask, 4)


def test_clamped_band_models_have_their_own_weights():
    """A final band that clamps its edges (the 'fast' preset) takes CLAMPED_WEIGHTS; the default, a dense model
    and 'reject' bands the default weights."""
    from prismstereo import thesis_setup1
    from prismstereo.classical.model import PrismStereo

    rig = thesis_setup1().downscaled(4)
    fast = PrismStereo(rig, (400.0, 800.0), dict(coarse_factor=2, band_edges="clamp"))
    torch.testing.assert_close(fast.final.calibration.weight.flatten(), torch.tensor(CLAMPED_WEIGHTS[0][:-1]))
    torch.testing.assert_close(fast.final.smoothed_calibration.weight.flatten(), torch.tensor(CLAMPED_WEIGHTS[1][:-1]))
    for model in (PrismStereo(rig, (400.0, 800.0), dict(coarse_factor=2)),
                  PrismStereo(rig, (400.0, 800.0), dict(coarse_factor=2, band_edges="clamp", dense=True))):
        torch.testing.assert_close(model.final.calibration.weight.flatten(), torch.tensor(DEFAULT_WEIGHTS[:-1]))
        weights = model.final.smoothed_calibration.weight.flatten()
        torch.testing.assert_close(weights, torch.tensor(SMOOTHED_WEIGHTS[:-1]))
    stage1 = dict(zip(FEATURES, CLAMPED_WEIGHTS[0], strict=False))
    assert stage1["coarse"] > 0 and stage1["roughness"] < 0 and stage1["offset"] < 0
    stage2 = dict(zip(SMOOTHED_FEATURES, CLAMPED_WEIGHTS[1], strict=False))
    # the spread and the agreement describe the same neighbourhood: with the spread, the clamped fit leaves the
    # agreement a small negative weight
    assert stage2["support"] > 0 and stage2["spread"] < 0 and stage2["spread"] < stage2["agreement"]
    # more evidence of a pixel's own never lowers its confidence: stage 2's own-confidence weights are >= 0
    for weights in (SMOOTHED_WEIGHTS, CLAMPED_WEIGHTS[1]):
        assert dict(zip(SMOOTHED_FEATURES, weights, strict=False))["confidence"] >= 0


def test_local_spread_exported_graph_matches_eager(tmp_path):
    """The exported form (two MaxPools per extreme) computes what the eager form (shifted maxima) computes, and
    the gradient path (max_pool2d) the same numbers."""
    ort = pytest.importorskip("onnxruntime")
    g = torch.Generator().manual_seed(4)
    x = torch.rand(2, 1, 20, 17, generator=g)
    mask = torch.rand(2, 1, 20, 17, generator=g) > 0.4

    class Graph(torch.nn.Module):
        def forward(self, values: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
            return local_spread(values, valid, 15)

    path = tmp_path / "spread.onnx"
    torch.onnx.export(Graph(), (x, mask), str(path), input_names=["values", "valid"], opset_version=18, dynamo=False)
    assert sum(node.op_type == "MaxPool" for node in __import__("onnx").load(str(path)).graph.node) == 4
    out = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(
        None, {"values": x.numpy(), "valid": mask.numpy()})[0]
    eager = local_spread(x, mask, 15)
    torch.testing.assert_close(torch.from_numpy(out), eager)
    torch.testing.assert_close(local_spread(x.clone().requires_grad_(), mask, 15).detach(), eager)


@pytest.mark.parametrize("names", ["FEATURES", "SMOOTHED_FEATURES"])
def test_model_exported_graph_matches_eager(tmp_path, names):
    """The exported form (one MatMul over the features, batch dynamic) computes the eager multiply-adds' numbers."""
    ort = pytest.importorskip("onnxruntime")
    onnx = pytest.importorskip("onnx")
    names = {"FEATURES": FEATURES, "SMOOTHED_FEATURES": SMOOTHED_FEATURES}[names]
    model = ConfidenceModel(names=names)
    x = torch.randn(3, len(names), 9, 11, generator=torch.Generator().manual_seed(6))
    path = tmp_path / "confidence.onnx"
    torch.onnx.export(model, (x[:1],), str(path), input_names=["features"], dynamic_axes={"features": {0: "B"}},
                      opset_version=18, dynamo=False)
    assert [n.op_type for n in onnx.load(str(path)).graph.node].count("MatMul") == 1
    out = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(None, {"features": x.numpy()})[0]
    torch.testing.assert_close(torch.from_numpy(out), model(x), atol=1e-6, rtol=0)


def test_confidence_threshold_keeps_the_most_within_the_bad_share():
    g = torch.Generator().manual_seed(0)
    c = torch.rand(2000, generator=g)
    right = torch.rand(2000, generator=g) < c  # a calibrated confidence: P(right) = c
    for bad in (0.02, 0.1, 0.3):
        value, kept = confidence_threshold(c, right, bad)
        sel = c >= value
        assert int(sel.sum()) == kept and float((~right[sel]).double().mean()) <= bad
        lower = c >= float(c[c < value].max())  # one more confidence level breaks the share
        assert float((~right[lower]).double().mean()) > bad
        assert abs(value - (1 - 2 * bad)) < 0.1  # above t the wrong share is the mean of 1 - c, (1 - t) / 2
    ties = torch.tensor([0.5, 0.5, 0.9])
    assert confidence_threshold(ties, torch.tensor([True, False, True]), 0.3).kept == 1  # both 0.5s or neither
    none = confidence_threshold(torch.tensor([0.9]), torch.tensor([False]), 0.1)
    assert none.kept == 0 and none.value != none.value
    with pytest.raises(ShapeError, match="right must be a bool tensor"):
        confidence_threshold(c, right.float(), 0.1)
    with pytest.raises(OptionError, match=r"bad must be in \[0, 1\)"):
        confidence_threshold(c, right, 1.0)
