import math

import pytest
import torch

from prismstereo import thesis_setup1
from prismstereo.synthetic import (
    CheckerTexture,
    CircleGridTexture,
    ConstantTexture,
    ImageTexture,
    NoiseTexture,
    SceneError,
    Texture,
    feature_size_for_depth,
)

F64 = torch.float64


def grid(n=200, extent=50.0, seed=0):
    gen = torch.Generator().manual_seed(seed)
    return (torch.rand(n, 2, generator=gen, dtype=F64) - 0.5) * extent


def test_feature_size_for_depth():
    rig = thesis_setup1()
    assert feature_size_for_depth(rig, 525.0, 3.0) == pytest.approx(3 * 525.0 * 0.00465 / 25.0)
    with pytest.raises(SceneError, match="must be positive"):
        feature_size_for_depth(rig, -5.0)


def test_noise_is_seeded_and_in_range():
    pts = grid()
    a, b, c = NoiseTexture(0.5, seed=1), NoiseTexture(0.5, seed=1), NoiseTexture(0.5, seed=2)
    va = a.sample(pts)
    assert isinstance(a, Texture) and va.shape == (200, 1) and va.dtype == F64
    assert torch.equal(va, b.sample(pts))
    assert not torch.allclose(va, c.sample(pts))
    assert va.min() >= 0 and va.max() <= 1
    big = NoiseTexture(0.5, seed=3).sample(grid(20000, 400.0))
    assert abs(big.mean().item() - 0.5) < 0.02 and 0.12 < big.std().item() < 0.24


def test_noise_is_band_limited():
    # smooth below the feature size, decorrelated above it
    tex = NoiseTexture(1.0, seed=4, octaves=1)
    base = grid(4000, 300.0)
    v0 = tex.sample(base)[:, 0]
    near = tex.sample(base + torch.tensor([0.1, 0.0], dtype=F64))[:, 0]
    far = tex.sample(base + torch.tensor([4.0, 0.0], dtype=F64))[:, 0]
    assert torch.corrcoef(torch.stack([v0, near]))[0, 1] > 0.95
    assert abs(torch.corrcoef(torch.stack([v0, far]))[0, 1]) < 0.3


def test_noise_is_periodic_with_its_lattice():
    tex = NoiseTexture(0.25, seed=5, octaves=1, lattice=64)
    pts = grid(100, 10.0)
    shifted = pts + torch.tensor([64 * 0.25, -64 * 0.25], dtype=F64)
    torch.testing.assert_close(tex.sample(pts), tex.sample(shifted), atol=1e-5, rtol=0)


def test_noise_rgb_channels_differ():
    v = NoiseTexture(0.5, seed=6, channels=3).sample(grid())
    assert v.shape == (200, 3) and not torch.allclose(v[:, 0], v[:, 1])


@pytest.mark.parametrize(
    "kwargs,match",
    [({"feature_mm": 0.0}, "feature_mm must be positive"),
     ({"feature_mm": 1.0, "channels": 2}, "channels must be 1 or 3"),
     ({"feature_mm": 1.0, "octaves": 0}, "need octaves >= 1")],
)
def test_noise_errors(kwargs, match):
    with pytest.raises(SceneError, match=match):
        NoiseTexture(**kwargs)


def test_image_texture_bilinear():
    img = torch.arange(12, dtype=torch.float32).view(1, 3, 4) / 11.0
    tex = ImageTexture(img, width_mm=4.0)  # 1 mm texels, height 3 mm
    assert tex.height_mm == 3.0
    centres = torch.tensor([[0.5, 0.5], [3.5, 2.5], [1.5, 1.5]], dtype=F64)
    torch.testing.assert_close(tex.sample(centres)[:, 0], torch.tensor([0.0, 11.0, 5.0], dtype=F64) / 11.0)
    between = tex.sample(torch.tensor([[1.0, 0.5], [1.5, 1.0]], dtype=F64))[:, 0]
    torch.testing.assert_close(between, torch.tensor([0.5, 3.0], dtype=F64) / 11.0)
    # border colour repeats outside
    outside = tex.sample(torch.tensor([[-5.0, -5.0]], dtype=F64))[:, 0]
    torch.testing.assert_close(outside, torch.tensor([0.0], dtype=F64))


@pytest.mark.parametrize(
    "image,match",
    [(torch.zeros(1, 0, 5), "non-empty"), (torch.zeros(2, 4, 4), "1 or 3 channels"),
     (torch.full((4, 4), 2.0), r"\[0, 1\]"),
     (torch.zeros(4, 4, dtype=torch.uint8), "floating-point"), ("picture.png", "must be a")],
)
def test_image_texture_errors(image, match):
    with pytest.raises(SceneError, match=match):
        ImageTexture(image, width_mm=10.0)


def test_checker_and_circles():
    chk = CheckerTexture(rows=3, cols=4, square_mm=10.0)
    pts = torch.tensor([[5.0, 5.0], [15.0, 5.0], [15.0, 15.0], [45.0, 5.0], [-1.0, 5.0]], dtype=F64)
    assert chk.sample(pts)[:, 0].tolist() == [0.0, 1.0, 0.0, 1.0, 1.0]
    circ = CircleGridTexture(2, 3, spacing_mm=10.0, radius_mm=2.0)
    pts = torch.tensor([[5.0, 5.0], [6.9, 5.0], [7.1, 5.0], [25.0, 15.0], [35.0, 5.0]], dtype=F64)
    assert circ.sample(pts)[:, 0].tolist() == [0.0, 0.0, 1.0, 0.0, 1.0]
    with pytest.raises(SceneError, match="checkerboard needs"):
        CheckerTexture(1, 4, 10.0)
    with pytest.raises(SceneError, match="radius < spacing / 2"):
        CircleGridTexture(3, 3, 10.0, 6.0)


def test_constant():
    assert ConstantTexture((0.1, 0.2, 0.3)).sample(grid(3))[1].tolist() == pytest.approx([0.1, 0.2, 0.3])
    with pytest.raises(SceneError, match="in \\[0, 1\\]"):
        ConstantTexture(1.5)


def test_noise_feature_size_controls_scale():
    small, large = NoiseTexture(0.2, seed=7, octaves=1), NoiseTexture(2.0, seed=7, octaves=1)
    base = grid(3000, 500.0)
    step = torch.tensor([0.6, 0.0], dtype=F64)
    corr_small = torch.corrcoef(torch.stack([small.sample(base)[:, 0], small.sample(base + step)[:, 0]]))[0, 1]
    corr_large = torch.corrcoef(torch.stack([large.sample(base)[:, 0], large.sample(base + step)[:, 0]]))[0, 1]
    assert corr_large > 0.9 > 0.5 > abs(corr_small)
    assert math.isfinite(corr_small)
