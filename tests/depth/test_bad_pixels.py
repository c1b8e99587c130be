"""BadPixels: non-finite pixels are data (their reach invalid, the rest as usual), out-of-range values refused."""

import pytest
import torch

from prismstereo import thesis_setup1
from prismstereo.classical import TemporalDepth
from prismstereo.depth.bad_pixels import BAD_PIXEL_REACH, BadPixels, discard
from prismstereo.depth.result import DepthResult
from prismstereo.epipolar.sweep import fit_sweep, positions_at, sweep_coefficients
from prismstereo.errors import ImageValueError, OptionError, PrismStereoError, ShapeError
from prismstereo.models import build_model
from prismstereo.synthetic import ImageFormation, fronto_parallel_plane, render

pytestmark = pytest.mark.usefixtures("one_thread")

Z = (450.0, 900.0)
NAN, INF = float("nan"), float("inf")


@pytest.fixture(scope="module")
def small():
    return thesis_setup1().downscaled(8)  # 128 x 96


@pytest.fixture(scope="module")
def plane():
    rig = thesis_setup1().downscaled(4)  # 256 x 192: every model kind runs on it
    return render(rig, fronto_parallel_plane(rig, 600.0, seed=5), ImageFormation(noise_sigma=1 / 255))


def _damaged(image: torch.Tensor, w_ref: int) -> torch.Tensor:
    """``image`` with dead pixels, a NaN patch in each half and an infinite one."""
    out = image.clone()
    out[..., 40:46, 30:36] = NAN
    out[..., 120:124, w_ref + 60:w_ref + 64] = NAN
    out[..., 150, 20] = INF
    out[..., 10, w_ref + 90] = -INF
    return out


def test_screen_shapes_and_clean_captures(small):
    guard = BadPixels(small, Z)
    image = torch.rand(2, 3, 96, 128, generator=torch.Generator().manual_seed(0))
    screened = guard(image)
    assert screened.touched.shape == (2, 1, 96, small.reference_width) and screened.touched.dtype == torch.bool
    assert torch.equal(screened.image, image) and not screened.touched.any()
    image[1, 2, 5, 7] = NAN  # one channel of one image
    screened = guard(image)
    assert bool(torch.isfinite(screened.image).all()) and screened.image[1, 2, 5, 7] == 0
    assert not screened.touched[0].any() and screened.touched[1, 0, 5, 7]


def test_touched_holds_every_pixel_a_bad_one_reaches(small):
    """Reference: each reference pixel's exact sweep at 400 points (< 0.2 px apart) against each bad pixel, and its
    own window; the mask must contain it (conservative) without marking most of the half."""
    r = 2
    h, w_ref = small.image_height, small.reference_width
    image = torch.rand(1, 1, h, small.image_width, generator=torch.Generator().manual_seed(1))
    bad = [(40, w_ref + 20), (10, 30), (11, 31), (70, 5), (90, w_ref + 60)]
    for y, x in bad:
        image[0, 0, y, x] = NAN
    touched = BadPixels(small, Z, radius=r)(image).touched[0, 0]
    uv = torch.stack(torch.meshgrid(torch.arange(w_ref, dtype=torch.float64), torch.arange(h, dtype=torch.float64),
                                    indexing="xy"), -1)
    coefficients = sweep_coefficients(fit_sweep(small, Z), uv).permute(2, 0, 1, 3)
    sweep = positions_at(coefficients, torch.linspace(-1, 1, 400, dtype=torch.float64))  # (S, h, w_ref, 2)
    rows, columns = torch.meshgrid(torch.arange(h), torch.arange(w_ref), indexing="ij")
    reach = torch.zeros(h, w_ref, dtype=torch.bool)
    for y, x in bad:
        if x >= w_ref:  # the other half: seen by the sweeps that pass within the window
            d = torch.maximum((sweep[..., 0] - x).abs(), (sweep[..., 1] - y).abs())
            reach |= (d <= r + 0.5).any(0)
        else:
            reach |= torch.maximum((rows - y).abs(), (columns - x).abs()) <= r
    assert reach.sum() > 100 and not (reach & ~touched).any()
    assert touched.float().mean() < 0.5


@pytest.mark.parametrize("kind", ["hybrid", "classical", "learned"])
def test_models_drop_what_bad_pixels_reach_and_keep_the_rest(kind, plane):
    rig = thesis_setup1().downscaled(4)
    model = build_model(rig, kind, Z).eval()
    w_ref = rig.reference_width
    damaged = _damaged(plane.image, w_ref)
    with torch.inference_mode():
        clean, out = model(plane.image), model(damaged)
        touched = model.bad_pixels(damaged).touched if kind != "hybrid" else None
    assert bool(torch.isfinite(out.confidence).all()) and bool(torch.isfinite(out.index).all())
    dropped = out.confidence == 0
    assert not (out.valid & dropped).any()
    assert dropped[..., 40:46, 30:36].all() and dropped[..., 150, 20].all()
    if touched is not None:
        assert not (out.valid & touched).any()
    truth = plane.depth[..., :w_ref]
    kept = ~dropped & (clean.confidence > 0)  # where both runs give a depth
    assert kept.float().mean() > 0.3

    def wrong(result):  # share of valid kept pixels off by > 1 %
        v = result.valid & kept
        return float((((result.depth - truth).abs() / truth > 0.01) & v).sum() / v.sum().clamp_min(1)), v.sum()

    (wrong_clean, n_clean), (wrong_out, n_out) = wrong(clean), wrong(out)
    assert wrong_out <= wrong_clean + 0.005 and n_out >= 0.98 * n_clean


def test_discard_and_gradients(small):
    ones = torch.ones(1, 1, 2, 2)
    result = DepthResult(ones, ones > 0, ones * 0.8, ones * 0, torch.zeros(1, 2, 2, 2))
    touched = torch.tensor([[[[True, False], [False, False]]]])
    out = discard(result, touched)
    assert out.valid.tolist() == [[[[False, True], [True, True]]]] and out.confidence[0, 0, 0, 0] == 0
    assert torch.equal(out.depth, result.depth)
    guard = BadPixels(small, Z).double()
    gen = torch.Generator().manual_seed(2)
    base = torch.rand(1, 1, 96, 128, dtype=torch.float64, generator=gen)
    base[..., 2, 2] = NAN  # a bad pixel among the differentiated ones: its gradient is 0, the others' 1

    def screened(patch: torch.Tensor) -> torch.Tensor:
        image = base.clone()
        image[..., :4, :4] = torch.where(torch.isnan(base[..., :4, :4]), base[..., :4, :4], patch)
        return guard(image).image[..., :4, :4]

    patch = torch.rand(1, 1, 4, 4, dtype=torch.float64, generator=gen).requires_grad_()
    torch.autograd.gradcheck(screened, (patch,))


def test_values_devices_and_options(small):
    guard = BadPixels(small, Z)
    with pytest.raises(ImageValueError, match=r"must be in \[0, 1\], got 0 to 255.*divide by 255"):
        guard(torch.linspace(0, 255, 96 * 128).view(1, 1, 96, 128))
    with pytest.raises(ImageValueError, match=r"got -0.5 to 0.5$"):
        guard(torch.linspace(-0.5, 0.5, 96 * 128).view(1, 1, 96, 128))
    guard(torch.linspace(-0.05, 1.05, 96 * 128).view(1, 1, 96, 128))  # a resampling filter's overshoot is accepted
    with pytest.raises(ShapeError, match="meta device .* the model is on cpu"):
        guard(torch.empty(1, 1, 96, 128, device="meta"))
    with pytest.raises(ShapeError, match="64x48 px but the rig's sensor is 128x96"):
        guard(torch.zeros(1, 1, 48, 64))
    with pytest.raises(OptionError, match="radius"):
        BadPixels(small, Z, radius=-1)
    model = build_model(small, "classical", Z)
    with pytest.raises(PrismStereoError, match="divide by 255"):
        model(torch.full((1, 1, 96, 128), 200.0))
    assert BAD_PIXEL_REACH >= 2  # at least the default 5 x 5 window's half


def test_the_temporal_band_drops_what_bad_pixels_reach(plane):
    rig = thesis_setup1().downscaled(4)
    model = build_model(rig, "classical", Z, config={"downsample": 2, "full_band": 2}).eval()
    tracker = TemporalDepth(model)
    with torch.inference_mode():
        prior = tracker.band_prior(*model(plane.image)[:3])
        tracked = tracker.track(_damaged(plane.image, rig.reference_width), prior)
    result = tracked.result
    assert bool(torch.isfinite(result.confidence).all()) and not result.valid[..., 40:46, 30:36].any()
    assert result.valid.float().mean() > 0.3
