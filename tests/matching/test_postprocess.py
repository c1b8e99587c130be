import pytest
import torch

from prismstereo import OptionError, ShapeError
from prismstereo.matching import fill_background, median_filter, subpixel_refine, subpixel_refine_guarded
from prismstereo.matching.postprocess import robust_mean, weighted_median

F64 = torch.float64


def test_median_filter_removes_outliers_and_keeps_ramps():
    ramp = torch.arange(12, dtype=F64).view(1, 1, 1, 12).expand(2, 1, 10, 12).clone() * 0.5
    noisy = ramp.clone()
    noisy[0, 0, 3, 4] = 40.0  # isolated spikes
    noisy[0, 0, 7, 8] = -3.0
    noisy[1, 0, 5, 5] = 11.0
    out = median_filter(noisy, 5)
    assert out.dtype == F64
    torch.testing.assert_close(out[..., 2:-2, 2:-2], ramp[..., 2:-2, 2:-2])  # a linear ramp is a fixed point
    assert median_filter(noisy, 1) is noisy


def test_median_filter_ignores_invalid_pixels():
    d = torch.tensor([[1.0, 2.0, 100.0, 3.0, 4.0]]).view(1, 1, 1, 5)
    ok = torch.tensor([[True, True, False, True, True]]).view(1, 1, 1, 5)
    out = median_filter(d, 5, ok)
    # column 1 sees valid 1, 2, 3 -> 2; column 3 sees 2, 3, 4 -> 3; even counts take the lower middle value
    assert out.flatten().tolist() == [1.0, 2.0, 100.0, 3.0, 3.0]
    none = torch.zeros_like(ok)
    assert torch.equal(median_filter(d, 3, none), d)


def test_median_filter_errors():
    d = torch.rand(1, 1, 4, 4)
    with pytest.raises(OptionError, match="window must be a positive odd int"):
        median_filter(d, 4)
    with pytest.raises(ShapeError, match="disparity must have shape"):
        median_filter(torch.rand(1, 2, 4, 4))
    with pytest.raises(ShapeError, match="valid must be a bool tensor"):
        median_filter(d, 3, torch.ones(1, 1, 4, 4))


def test_fill_background_takes_the_lower_neighbour():
    # background 3, an occluded band (invalid) left of a foreground at 9, the left border invalid too
    d = torch.tensor([0.0, 0.0, 3.0, 3.0, 0.0, 0.0, 9.0, 9.0, 0.0]).view(1, 1, 1, 9).repeat(2, 1, 3, 1)
    ok = d > 0
    ok[1, :, 1] = False  # a row without valid pixels stays unfilled
    out, filled = fill_background(d.to(F64), ok)
    assert out.dtype == F64
    assert out[0, 0, 0].tolist() == [3.0, 3.0, 3.0, 3.0, 3.0, 3.0, 9.0, 9.0, 9.0]
    assert filled[0, 0, 0].tolist() == [True, True, False, False, True, True, False, False, True]
    assert not filled[1, 0, 1].any() and torch.equal(out[1, 0, 1], d[1, 0, 1].to(F64))


def test_fill_background_errors():
    d = torch.rand(1, 1, 4, 4)
    with pytest.raises(ShapeError, match="valid must be a bool tensor"):
        fill_background(d, None)
    with pytest.raises(ShapeError, match="valid must be a bool tensor"):
        fill_background(d, torch.ones(1, 1, 4, 5, dtype=torch.bool))


def test_subpixel_refine_guarded():
    x = torch.arange(8, dtype=F64).view(1, 8, 1, 1)
    local = torch.cat([(x - 3.3).abs(), (x - 3.3).abs().clamp(max=0.3)], dim=-1)  # the second one is flat
    aggregated = ((x - 3.0).abs() * 5).expand(1, 8, 1, 2)
    index = torch.full((1, 1, 1, 2), 3, dtype=torch.long)
    out = subpixel_refine_guarded(local, index, aggregated)
    assert float(out[0, 0, 0, 0]) == pytest.approx(3.3)  # the local fit where it agrees with the winner
    assert float(out[0, 0, 0, 1]) == float(subpixel_refine(aggregated, index)[0, 0, 0, 1])  # fallback
    assert float(subpixel_refine_guarded(local, index)[0, 0, 0, 1]) == 3.0  # no fallback: integer
    with pytest.raises(ShapeError, match="fallback"):
        subpixel_refine_guarded(local, index, aggregated[..., :1])
    with pytest.raises(OptionError, match="Unknown method 'cubic'"):
        subpixel_refine_guarded(local, index, method="cubic")


def naive_weighted_median(d, guide, valid, r, sigma_s, sigma_c, step):
    """One pixel at a time: sort the valid taps, take the first whose cumulative weight reaches half."""
    _, _, h, w = d.shape
    out = d.clone()
    for y in range(h):
        for x in range(w):
            if not valid[0, 0, y, x]:
                continue
            values, weights = [], []
            for dy in range(-(r // step) * step, r + 1, step):
                for dx in range(-(r // step) * step, r + 1, step):
                    yy, xx = y + dy, x + dx
                    if 0 <= yy < h and 0 <= xx < w and valid[0, 0, yy, xx]:
                        colour = float((guide[0, :, yy, xx] - guide[0, :, y, x]).abs().max())
                        values.append(float(d[0, 0, yy, xx]))
                        weights.append(torch.exp(torch.tensor(-(dy * dy + dx * dx) / sigma_s**2
                                                              - (colour / sigma_c) ** 2, dtype=F64)))
            order = sorted(range(len(values)), key=lambda i: values[i])
            total, acc = sum(weights), 0.0
            for i in order:
                acc += weights[i]
                if acc >= 0.5 * total:
                    out[0, 0, y, x] = values[i]
                    break
    return out


@pytest.mark.parametrize("step", [1, 2])
def test_weighted_median_matches_the_reference(step):
    gen = torch.Generator().manual_seed(5)
    d = torch.rand(1, 1, 7, 9, generator=gen, dtype=F64) * 10
    guide = torch.rand(1, 3, 7, 9, generator=gen, dtype=F64)
    valid = torch.rand(1, 1, 7, 9, generator=gen) > 0.3
    out = weighted_median(d, guide, valid, 3, 2.0, 0.3, step)
    assert out.dtype == F64 and out.shape == d.shape
    torch.testing.assert_close(out, naive_weighted_median(d, guide, valid, 3, 2.0, 0.3, step))
    assert torch.equal(out[~valid], d[~valid])  # invalid pixels do not change


def test_weighted_median_follows_colour_edges():
    # a foreground (disparity 8.25) whose window-based match fattened a column into the background (2): the
    # colour weights give it the background's disparity back; sub-pixel values are kept as they are
    guide = torch.zeros(2, 1, 12, 16)
    guide[..., 8:] = 1.0
    truth = torch.where(guide > 0, 8.25, 2.0)
    fat = truth.clone()
    fat[..., 7] = 8.25
    out = weighted_median(fat, guide[:1], radius=4, sigma_space=4.0, sigma_colour=0.1)
    assert torch.equal(out, truth)
    assert torch.equal(median_filter(fat, 3)[..., 7], fat[..., 7])  # a plain median keeps the fattening


def test_weighted_median_errors():
    d, guide = torch.rand(1, 1, 4, 5), torch.rand(1, 3, 4, 5)
    with pytest.raises(ShapeError, match="must match the disparity"):
        weighted_median(d, torch.rand(1, 3, 4, 6))
    with pytest.raises(ShapeError, match="must match the disparity"):
        weighted_median(torch.rand(2, 1, 4, 5), torch.rand(3, 3, 4, 5))
    with pytest.raises(ShapeError, match="valid must be a bool tensor"):
        weighted_median(d, guide, torch.ones(1, 1, 4, 5))
    with pytest.raises(OptionError, match="radius must be an int >= 1"):
        weighted_median(d, guide, radius=0)
    with pytest.raises(OptionError, match="step must be an int >= 1"):
        weighted_median(d, guide, step=0)
    with pytest.raises(OptionError, match="sigma_space and sigma_colour must be > 0"):
        weighted_median(d, guide, sigma_colour=0.0)


def _plane_with_noise(seed=0, h=40, w=48):
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.arange(h, dtype=F64), torch.arange(w, dtype=F64), indexing="ij")
    plane = (0.02 * xx - 0.01 * yy + 3.0).view(1, 1, h, w)
    return plane, plane + 0.05 * torch.randn(1, 1, h, w, generator=g, dtype=F64)


def test_robust_mean_averages_noise_on_a_plane_and_keeps_a_step():
    plane, noisy = _plane_with_noise()
    weight = torch.full_like(noisy, 0.3)  # no pixel confident enough to keep a disagreeing value
    out = robust_mean(noisy, weight, 9, 0.2)
    assert out.values.shape == noisy.shape and out.values.dtype == F64
    inner = (..., slice(4, -4), slice(4, -4))  # a centred window's mean of a plane is the plane
    err_before = (noisy - plane)[inner].abs().mean()
    err_after = (out.values - plane)[inner].abs().mean()
    assert err_after < 0.25 * err_before
    assert torch.allclose(out.agreement[inner], torch.ones_like(out.agreement[inner]))
    assert torch.allclose(out.support, weight)  # the window's mean weight
    step = torch.where(torch.arange(48, dtype=F64) < 24, 3.0, 5.0).expand(1, 1, 40, 48)
    sharp = robust_mean(step, torch.full_like(step, 0.3), 9, 0.2).values
    assert torch.allclose(sharp, step)  # the other side of a step is further than the tolerance


def test_robust_mean_fills_unconfident_outliers_and_keeps_confident_thin_structures():
    flat = torch.full((1, 1, 21, 21), 2.0, dtype=F64)
    weight = torch.full_like(flat, 0.4)
    x = flat.clone()
    x[0, 0, 10, 10] = 9.0  # an unconfident outlier: takes its neighbourhood's value
    assert float(robust_mean(x, weight, 7, 0.5).values[0, 0, 10, 10]) == pytest.approx(2.0)
    rod = flat.clone()
    rod[0, 0, :, 10] = 1.0  # a confident one-pixel rod in front of the wall
    w_rod = weight.clone()
    w_rod[0, 0, :, 10] = 0.9
    out = robust_mean(rod, w_rod, 7, 0.5).values
    assert torch.equal(out[0, 0, :, 10], rod[0, 0, :, 10])
    isolated = robust_mean(x, torch.zeros_like(x), 7, 0.5).values  # no support: own values
    assert torch.equal(isolated, x)


def test_robust_mean_errors_and_gradcheck():
    _, noisy = _plane_with_noise(h=8, w=9)
    weight = torch.rand(1, 1, 8, 9, generator=torch.Generator().manual_seed(3), dtype=F64)
    with pytest.raises(OptionError, match="window must be an odd int >= 3"):
        robust_mean(noisy, weight, 4, 0.1)
    with pytest.raises(OptionError, match="tolerance must be a finite number > 0"):
        robust_mean(noisy, weight, 5, 0.0)
    with pytest.raises(ShapeError, match="weight"):
        robust_mean(noisy, weight[..., :5], 5, 0.1)
    with pytest.raises(ShapeError):
        robust_mean(noisy[0], weight[0], 5, 0.1)
    x = noisy.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda v: robust_mean(v, weight, 5, 0.1).values, (x,), eps=1e-6, atol=1e-5)


def test_robust_mean_exported_graph_matches_eager(tmp_path):
    """The exported form (AveragePool boxes) gives the eager numbers, outputs and features alike."""
    ort = pytest.importorskip("onnxruntime")
    _, noisy = _plane_with_noise(h=24, w=30)
    x = noisy.float()
    x[..., 10:, 12:] += 3.0  # a step
    weight = torch.rand(1, 1, 24, 30, generator=torch.Generator().manual_seed(5))

    class Graph(torch.nn.Module):
        def forward(self, values: torch.Tensor, w: torch.Tensor):
            return tuple(robust_mean(values, w, 7, 0.2))

    path = tmp_path / "robust.onnx"
    torch.onnx.export(Graph(), (x, weight), str(path), input_names=["values", "weight"], opset_version=18,
                      dynamo=False)
    outs = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(
        None, {"values": x.numpy(), "weight": weight.numpy()})
    for got, want in zip(outs, robust_mean(x, weight, 7, 0.2), strict=True):
        torch.testing.assert_close(torch.from_numpy(got), want, rtol=1e-5, atol=1e-5)
