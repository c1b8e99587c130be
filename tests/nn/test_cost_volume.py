"""PrismCostVolume and sweep_grid: shapes of both modes and groups, the grid against exact projections, the
correlation against manual bilinear samples, a constant-disparity capture recovered by depth_regression,
float64 gradcheck (features and one rig parameter), errors, dtype / device buffers and onnxruntime parity."""

import kornia
import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch import nn

from prismstereo import thesis_setup1
from prismstereo.epipolar.grids import depth_hypotheses, normalise_right_grid
from prismstereo.errors import OptionError, PrismStereoError, RigError, ShapeError
from prismstereo.geometry import points_at_depth, project_points, trace_pixels
from prismstereo.matching.sweep_cost import sample_points, sample_slices
from prismstereo.nn import PrismCostVolume, depth_regression, sweep_grid

pytestmark = pytest.mark.usefixtures("one_thread")

Z_RANGE = (400.0, 1000.0)


@pytest.fixture(scope="module")
def rig():
    return thesis_setup1().downscaled(4)  # 256 x 192: features at scale 4 are 64 x 48, w_ref 32


@pytest.fixture(scope="module")
def volume(rig):
    return PrismCostVolume(rig, Z_RANGE, num_hypotheses=8, scale=4)


def _features(volume, channels=8, batch=2, seed=0, dtype=torch.float32):
    gen = torch.Generator().manual_seed(seed)
    return torch.randn(batch, channels, volume.height, volume.width, generator=gen, dtype=dtype)


def test_shapes_of_modes_and_groups(rig, volume):
    feats = _features(volume)
    assert (volume.height, volume.width, volume.reference_width) == (48, 64, 32)
    assert volume(feats).shape == (2, 8, 48, 32)
    assert volume.depths.shape == (8,) and volume.valid.shape == (8, 48, 32) and volume.valid.dtype == torch.bool
    grouped = PrismCostVolume(rig, Z_RANGE, 8, 4, groups=4)
    assert grouped(feats).shape == (2, 4, 8, 48, 32)
    concat = PrismCostVolume(rig, Z_RANGE, 8, 4, mode="concat")
    assert concat(feats).shape == (2, 16, 8, 48, 32)
    # groups = C: per-channel products; their mean over the groups is the one-group correlation
    per_channel = PrismCostVolume(rig, Z_RANGE, 8, 4, groups=8)(feats)
    torch.testing.assert_close(per_channel.mean(1), volume(feats), atol=1e-6, rtol=1e-5)


def test_depths_uniform_in_inverse_depth(volume):
    torch.testing.assert_close(volume.depths, depth_hypotheses(*Z_RANGE, 8).float())


def test_grid_matches_exact_projection_at_full_resolution():
    """scale = 1: the grid is the exact projection of the point at depth Z on the reference pixel's ray."""
    small = thesis_setup1().downscaled(8)
    g = sweep_grid(small, Z_RANGE, 5, scale=1)
    d, h, w_ref = g.valid.shape
    assert (h, w_ref) == (small.image_height, small.reference_width) and g.uv.dtype == torch.float64
    uv_ref = torch.stack(torch.meshgrid(torch.arange(w_ref, dtype=torch.float64),
                                        torch.arange(h, dtype=torch.float64), indexing="xy"), -1)
    rays = trace_pixels(small, uv_ref)
    for i, z in enumerate(g.depths):
        proj = project_points(small, points_at_depth(rays, z), "right")
        ok = g.valid[i] & proj.valid
        assert ok.sum() > 0.5 * h * w_ref
        assert float((g.uv[i] - proj.uv).norm(dim=-1)[ok].max()) < 1e-3
    torch.testing.assert_close(g.grid, normalise_right_grid(g.uv, small))


def test_validity_rule(rig, volume):
    """Valid samples lie inside the right half (between its pixel centres) of the binned sensor; the volume
    is 0 wherever a sample is not valid, in both modes."""
    g = sweep_grid(rig, Z_RANGE, 8, 4)
    torch.testing.assert_close(g.valid, volume.valid)
    u, v = g.uv[..., 0][g.valid], g.uv[..., 1][g.valid]
    assert float(u.min()) >= volume.reference_width - 1e-3 and float(u.max()) <= volume.width - 1 + 1e-3
    assert float(v.min()) >= -1e-3 and float(v.max()) <= volume.height - 1 + 1e-3
    assert 0.5 < float(g.valid.float().mean()) < 1.0  # some hypotheses leave the right half's view
    feats = _features(volume)
    assert float(volume(feats)[:, ~volume.valid].abs().max()) == 0.0
    concat = PrismCostVolume(rig, Z_RANGE, 8, 4, mode="concat")(feats)
    assert float(concat[:, :, ~volume.valid].abs().max()) == 0.0


def test_correlation_is_the_channel_mean_of_bilinear_samples(volume):
    feats = _features(volume, channels=4, batch=1, seed=1)
    w_ref = volume.reference_width
    right = feats[..., w_ref:]
    uv = sweep_grid(volume.rig, Z_RANGE, 8, 4).uv.float()  # binned full-sensor pixels
    sampled = sample_points(right, (uv[..., 0] - w_ref).unsqueeze(0), uv[..., 1].unsqueeze(0))  # (1, C, D, h, w)
    expected = (feats[..., :w_ref].unsqueeze(2) * sampled).mean(1) * volume.valid
    torch.testing.assert_close(volume(feats), expected, atol=1e-5, rtol=1e-5)


def test_constant_disparity_recovered_by_regression(volume):
    """The reference half painted as the right half sampled on the sweep at hypothesis k: correlation peaks at
    k and the soft-argmax gives depths[k] wherever hypotheses k - 1 .. k + 1 are valid."""
    gen = torch.Generator().manual_seed(3)
    w_ref, k = volume.reference_width, 4
    right = torch.randn(1, 16, volume.height, volume.width - w_ref, generator=gen)
    right = F.normalize(kornia.filters.gaussian_blur2d(right, (7, 7), (0.7, 0.7), border_type="reflect"), dim=1)
    reference = sample_slices(right, volume.grid[k:k + 1].unsqueeze(0), shared=True)[:, :, 0]
    cost = volume(torch.cat([reference, right], -1))
    out = depth_regression(cost, volume.depths, volume.valid, temperature=0.002)
    inner = volume.valid[k - 1:k + 2].all(0)
    assert int(inner.sum()) > 1000
    assert float((cost[0].argmax(0)[inner] == k).float().mean()) > 0.99
    z0, z1 = Z_RANGE
    index = (1.0 / out.depth[0, 0] - 1.0 / z0) / (1.0 / z1 - 1.0 / z0) * 7  # fractional hypothesis index
    error = (index - k).abs()[inner]
    assert float(error.median()) < 0.01 and float((error < 0.05).float().mean()) > 0.95
    rel = ((out.depth[0, 0] - volume.depths[k]).abs() / volume.depths[k])[inner]
    assert float(rel.median()) < 1e-3
    assert float(out.confidence[0, 0][inner].mean()) > 0.98


def test_gradcheck_features():
    tiny = thesis_setup1().downscaled(8)
    volume = PrismCostVolume(tiny, Z_RANGE, 4, 8).double()  # 12 x 16 features, w_ref 8
    feats = torch.randn(1, 2, 12, 16, dtype=torch.float64, generator=torch.Generator().manual_seed(0),
                        requires_grad=True)
    assert volume.grid.dtype == torch.float64
    assert torch.autograd.gradcheck(volume, (feats,), eps=1e-6, atol=1e-6)
    grouped = PrismCostVolume(tiny, Z_RANGE, 4, 8, groups=2, mode="correlation").double()
    assert torch.autograd.gradcheck(grouped, (feats,), eps=1e-6, atol=1e-6)
    concat = PrismCostVolume(tiny, Z_RANGE, 4, 8, mode="concat").double()
    assert torch.autograd.gradcheck(concat, (feats,), eps=1e-6, atol=1e-6)
    regress = lambda f: depth_regression(volume(f), volume.depths, volume.valid, 0.5)  # noqa: E731
    assert torch.autograd.gradcheck(regress, (feats,), eps=1e-6, atol=1e-6)


def test_gradients_reach_a_rig_parameter():
    """RigParameters requiring grad: the grid is recomputed in forward and differentiable w.r.t. the focal length
    (float64 gradcheck; the projection's implicit gradient uses a finite-difference Jacobian, hence atol)."""
    tiny = thesis_setup1().downscaled(8)
    params = tiny.parameters(dtype=torch.float64, requires_grad=True)
    volume = PrismCostVolume(params, Z_RANGE, 3, 8)
    assert volume.rig_gradients
    gen = torch.Generator().manual_seed(2)
    feats = kornia.filters.gaussian_blur2d(torch.randn(1, 2, 12, 16, generator=gen, dtype=torch.float64),
                                           (5, 5), (1.0, 1.0))
    volume(feats).sum().backward()
    assert params.f.grad is not None and float(params.f.grad.abs()) > 0
    assert params.alpha.grad is not None and float(params.alpha.grad.abs()) > 0

    weights = torch.randn(1, 3, 12, 8, generator=gen, dtype=torch.float64)

    def of_focal(f):  # a scalar: one backward pass instead of one per volume entry
        volume.rig = params._replace(f=f)
        return (volume(feats) * weights).sum()

    focal = params.f.detach().clone().requires_grad_(True)
    assert torch.autograd.gradcheck(of_focal, (focal,), eps=1e-6, atol=1e-5, rtol=1e-3)


def test_static_rig_parameters_give_the_rig_grid(rig, volume):
    params = PrismCostVolume(rig.parameters(dtype=torch.float64), Z_RANGE, 8, 4)
    assert not params.rig_gradients
    torch.testing.assert_close(params.grid, volume.grid)
    assert torch.equal(params.valid, volume.valid)


def test_buffers_follow_to_and_the_volume_follows_the_features(volume):
    double = PrismCostVolume(volume.rig, Z_RANGE, 8, 4).to(torch.float64)
    assert double.grid.dtype == double.depths.dtype == torch.float64 and double.valid.dtype == torch.bool
    assert {"sampler.coefficients", "sampler.valid", "depths"} <= set(dict(double.named_buffers()))
    assert volume(_features(volume, dtype=torch.float64)).dtype == torch.float64  # float32 buffers, float64 input


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"mode": "cosine"}, OptionError, "Choose from: 'correlation', 'concat'"),
        ({"groups": 0}, OptionError, "groups must be an int >= 1"),
        ({"groups": 2, "mode": "concat"}, OptionError, "groups must be 1 with mode 'concat'"),
        ({"scale": 0}, OptionError, "scale must be an int >= 1"),
        ({"scale": 2.0}, OptionError, "scale must be an int >= 1"),
        ({"scale": 512}, OptionError, "leaves no binned image"),
        ({"num_hypotheses": 1}, OptionError, "num_hypotheses must be an int >= 2"),
        ({"z_range_mm": (1000.0, 400.0)}, RigError, "z_range_mm"),
    ],
)
def test_bad_options(rig, kwargs, error, match):
    options = {"z_range_mm": Z_RANGE, "num_hypotheses": 4, "scale": 4, **kwargs}
    with pytest.raises(error, match=match) as info:
        PrismCostVolume(rig, **options)
    assert isinstance(info.value, PrismStereoError)


def test_bad_features(rig, volume):
    with pytest.raises(ShapeError, match=r"features must have shape \(B, C, H, W\)"):
        volume(torch.zeros(8, 48, 64))
    with pytest.raises(ShapeError, match=r"features must be \(B, C, 48, 64\) \(the sensor binned by 4\)"):
        volume(torch.zeros(1, 8, 96, 128))  # full-resolution features into a scale-4 volume
    with pytest.raises(ShapeError, match="not a multiple of groups=3"):
        PrismCostVolume(rig, Z_RANGE, 4, 4, groups=3)(torch.zeros(1, 8, 48, 64))
    with pytest.raises(RigError, match="BiPrismRig or RigParameters"):
        sweep_grid("setup1", Z_RANGE, 4)


@pytest.mark.filterwarnings("ignore::torch.jit.TracerWarning", "ignore::DeprecationWarning")
def test_onnx_parity_of_a_tiny_network(tmp_path, rig):
    """Conv2d -> PrismCostVolume (2 groups) -> depth_regression exported (opset 18, TorchScript exporter, batch
    dynamic) and run in onnxruntime on a batch of another size."""
    ort = pytest.importorskip("onnxruntime")
    onnx = pytest.importorskip("onnx")

    class Net(nn.Module):
        def __init__(self):
            super().__init__()
            self.features = nn.Conv2d(1, 8, 3, padding=1)
            self.volume = PrismCostVolume(rig, Z_RANGE, 8, 4, groups=2)

        def forward(self, image):
            cost = self.volume(self.features(image)).mean(1)  # (B, D, h, w_ref)
            out = depth_regression(cost, self.volume.depths, self.volume.valid, temperature=0.5)
            return out.depth, out.confidence

    torch.manual_seed(0)
    net = Net().eval()
    path = tmp_path / "net.onnx"
    torch.onnx.export(net, (torch.rand(1, 1, 48, 64),), str(path), opset_version=18, dynamo=False,
                      input_names=["features"], output_names=["depth", "confidence"],
                      dynamic_axes={"features": {0: "batch"}, "depth": {0: "batch"}, "confidence": {0: "batch"}})
    onnx.checker.check_model(onnx.load(str(path)))
    image = torch.rand(3, 1, 48, 64, generator=torch.Generator().manual_seed(4))
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    depth, confidence = session.run(None, {"features": image.numpy()})
    with torch.no_grad():
        ref_depth, ref_confidence = net(image)
    assert depth.shape == (3, 1, 48, 32) and np.isfinite(depth).all()
    np.testing.assert_allclose(depth / ref_depth.numpy(), 1.0, atol=1e-4)  # relative: depths are ~400-1000 mm
    np.testing.assert_allclose(confidence, ref_confidence.numpy(), atol=1e-4)
