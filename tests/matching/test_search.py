import dataclasses

import pytest
import torch

from prismstereo import OptionError, PrismStereo, ShapeError, StereoConfig, thesis_setup1
from prismstereo.classical.defaults import resolve_level
from prismstereo.conventions import to_grey
from prismstereo.epipolar.series import series_at
from prismstereo.epipolar.sweep import depth_to_sweep
from prismstereo.matching import (
    FineBand,
    LevelResult,
    RectifiedSearch,
    SweepSearch,
    box_filter,
    decide,
    extend_estimate,
    shift_cost,
)
from prismstereo.matching.band import STRIP_VOXELS, texture_of
from prismstereo.matching.cost import reference_moments
from prismstereo.matching.search import similarity
from prismstereo.synthetic import ImageFormation, fronto_parallel_plane, render
from tests.conftest import scaled_rig


@pytest.fixture(scope="module")
def plane():
    rig = scaled_rig(thesis_setup1(), 4)
    cap = render(rig, fronto_parallel_plane(rig, 600.0, seed=3), ImageFormation(supersample=2, noise_sigma=1 / 255))
    return rig, cap


GUIDED = dict(cost="ad_gradient", aggregation="guided", box=1)


@pytest.mark.parametrize("sampling, directions, extra", [("rectified", 4, {}), ("rectified", 2, {}), ("sweep", 4, {}),
                                                         ("rectified", 4, GUIDED), ("sweep", 4, GUIDED)],
                         ids=["rectified", "rectified-rows", "sweep", "rectified-guided", "sweep-guided"])
def test_searches_share_one_interface_and_find_the_plane(plane, sampling, directions, extra):
    """Both coarse searches: the same call, a LevelResult at the level's resolution, the plane's sweep
    coordinate at most pixels the other half sees (the rectified volume stays transposed except with
    2-direction SGM, which scans rows only), also with the per-pixel 'ad_gradient' cost aggregated by the guided
    filter."""
    rig, cap = plane
    model = PrismStereo(rig, (450.0, 900.0), dict(coarse_factor=2, sampling=sampling, directions=directions, **extra))
    search = model.final.search
    assert isinstance(search, RectifiedSearch if sampling == "rectified" else SweepSearch)
    if sampling == "rectified":
        assert search.transposed == (directions != 2)
    ref, other = model.split(cap.image)
    with torch.no_grad():
        res = search(model.final.coarse(ref), model.final.coarse(other), final=False)
    assert isinstance(res, LevelResult)
    assert res.s.shape == res.valid.shape == (1, 1, rig.image_height // 2, rig.reference_width // 2)
    truth = depth_to_sweep(torch.tensor(600.0), torch.tensor(model.z_range))
    step = 2.0 / (search.num_hypotheses - 1)
    cov = torch.nn.functional.avg_pool2d(cap.covisible[..., :rig.reference_width].float(), 2) > 0.99
    good = ((res.s - truth).abs() < step)[res.valid & cov]
    assert good.float().mean() > 0.95 and (res.valid & cov).sum() > 0.8 * cov.sum()
    assert float(res.confidence.min()) >= 0 and float(res.confidence.max()) <= 1


def test_fine_band_strips_give_the_whole_image(plane, monkeypatch):
    rig, cap = plane
    model = PrismStereo(rig, (450.0, 900.0), dict(coarse_factor=2, smoothing=0))  # the band with its match
    assert isinstance(model.final.fine, FineBand) and model.final.fine.band == 3
    ref, other = model.split(cap.image)
    s0 = torch.full((1, 1, rig.image_height, rig.reference_width), float(depth_to_sweep(
        torch.tensor(600.0), torch.tensor(model.z_range)))) + 0.01
    ok0 = torch.ones_like(s0, dtype=torch.bool)
    with torch.no_grad():
        monkeypatch.setattr(model.final.fine, "strip_voxels", 10**9)
        whole = model.final.fine(ref, other, s0, ok0, model.final.series, model.final.interval)
        monkeypatch.setattr(model.final.fine, "strip_voxels", 1)  # 16-row strips
        strips = model.final.fine(ref, other, s0, ok0, model.final.series, model.final.interval)
    for a, b in zip(whole, strips, strict=True):
        assert torch.equal(a, b)
    # started 0.01 off (0.15 px; a hypothesis step is 0.069 here), the band finds the plane to ~0.04 px
    truth = depth_to_sweep(torch.tensor(600.0), torch.tensor(model.z_range))
    err = (whole.s - truth).abs()[whole.valid & cap.covisible[..., :rig.reference_width]]
    assert err.numel() > 0.95 * cap.covisible[..., :rig.reference_width].sum()
    assert err.median() < 0.005 and err.quantile(0.9) < 0.02
    # the band's match (interpolated between its samples) is the exact sweep's position at s
    exact = torch.cat(series_at(model.final.series, whole.s), 1)
    assert (whole.match - exact).abs().amax(1, keepdim=True)[whole.valid].max() < 1e-3
    # without the match (a smoothing model computes it after moving s): the same estimate, whole or in strips
    fine = model.final.fine
    bare = FineBand(fine.options, fine.band, fine.step, fine.split, with_match=False)
    for bad in (0.0, 1.5):
        with pytest.raises(OptionError, match=r"vertex_limit must be a number in \(0, 1\]"):
            FineBand(fine.options, fine.band, fine.step, fine.split, vertex_limit=bad)
    with pytest.raises(OptionError, match="a fine band needs resolved options"):
        model.config.band_options()  # band_edges and refinement still None
    with pytest.raises(OptionError, match="Unknown band_edges 'edge'"):
        FineBand(fine.options._replace(band_edges="edge"), fine.band, fine.step, fine.split)
    assert PrismStereo(rig, (450.0, 900.0), dict(coarse_factor=2)).final.fine.with_match is False
    with torch.no_grad():
        for voxels in (10**9, 1):
            monkeypatch.setattr(bare, "strip_voxels", voxels)
            res = bare(ref, other, s0, ok0, model.final.series, model.final.interval)
            assert res.match is None and torch.equal(res.s, whole.s) and torch.equal(res.valid, whole.valid)


def test_fine_band_edges_reject_or_clamp(plane):
    """A pixel whose match lies beyond its band (the best hypothesis on the band's edge) is invalid with
    band_edges='reject'; 'clamp' refines it from the edge's inner neighbour: s moves towards the truth, at most
    half a step beyond that neighbour, with the exact sweep's match there and that hypothesis' (low) confidence.
    Pixels whose best hypothesis is inside the band are the same either way."""
    rig, cap = plane
    reject = PrismStereo(rig, (450.0, 900.0), dict(coarse_factor=2, band_edges="reject", smoothing=0))
    clamp = PrismStereo(rig, (450.0, 900.0), dict(coarse_factor=2, band_edges="clamp", smoothing=0))
    assert reject.final.fine.band_edges == "reject" and clamp.final.fine.band_edges == "clamp"
    ref, other = reject.split(cap.image)
    truth = float(depth_to_sweep(torch.tensor(600.0), torch.tensor(reject.z_range)))
    h, w = rig.image_height, rig.reference_width
    step, band = reject.final.fine.step, reject.final.fine.band
    beyond = torch.zeros(1, 1, h, w, dtype=torch.bool)
    beyond[..., w // 2:] = True  # the right half starts band + 1.5 steps off: the truth lies outside the band
    s0 = torch.where(beyond, torch.tensor(truth - (band + 1.5) * step), torch.tensor(truth + 0.01))
    ok0 = torch.ones_like(s0, dtype=torch.bool)
    with torch.no_grad():
        r = reject.final.fine(ref, other, s0, ok0, reject.final.series, reject.final.interval)
        c = clamp.final.fine(ref, other, s0, ok0, clamp.final.series, clamp.final.interval)
    cov = cap.covisible[..., :w]
    assert r.valid[~beyond & cov].float().mean() > 0.95 and r.valid[beyond & cov].float().mean() < 0.02
    for a, b in zip(r, c, strict=True):  # valid under 'reject': the same numbers
        assert torch.equal(a[r.valid.expand_as(a)], b[r.valid.expand_as(b)])
    clamped = c.valid & ~r.valid & beyond & cov
    assert clamped.sum() > 0.95 * (beyond & cov).sum()
    moved = (c.s - s0)[clamped] / step  # from the inner neighbour (band - 1 steps up) at most half a step on
    assert float(moved.abs().min()) >= band - 1 - 1e-4 and float(moved.abs().max()) <= band - 0.5 + 1e-4
    assert float((moved > band - 1 + 1e-3).float().mean()) > 0.9, moved.unique(return_counts=True)  # towards truth
    exact = torch.cat(series_at(clamp.final.series, c.s), 1)
    assert (c.match - exact).abs().amax(1, keepdim=True)[clamped].max() < 1e-3
    # that hypothesis is still 1-1.5 steps from the truth: it matches worse than the true match (measured
    # median NCC 0.70 against ~0.99), so min_confidence / reach_confidence can still reject it
    assert c.confidence[clamped].median() < r.confidence[r.valid].median() - 0.2


@pytest.mark.parametrize("refinement", [None, "soft_argmin"])
def test_fine_band_of_three_clamped_is_the_centre_refined(plane, refinement):
    """band=1 with 'clamp': the winner is always the centre, taken by static slices instead of a winner search
    and gathers; on the pixels whose best of the three is the centre (valid with 'reject') the numbers are
    bitwise those of the searched winner, and the pixels 'reject' drops are refined from the centre: s within
    half a step of s0 (the parabola; a soft-argmin stays within the band), the match the exact sweep's position
    at s."""
    rig, cap = plane
    options = dict(coarse_factor=2, band=1, refinement=refinement, wide_box=0, smoothing=0)  # the band's own box only
    reject = PrismStereo(rig, (450.0, 900.0), {"band_edges": "reject", **options})
    clamp = PrismStereo(rig, (450.0, 900.0), {"band_edges": "clamp", **options})
    ref, other = reject.split(cap.image)
    truth = float(depth_to_sweep(torch.tensor(600.0), torch.tensor(reject.z_range)))
    s0 = torch.full((1, 1, rig.image_height, rig.reference_width), truth + 0.45 * reject.final.fine.step)
    ok0 = torch.ones_like(s0, dtype=torch.bool)
    with torch.no_grad():
        r = reject.final.fine(ref, other, s0, ok0, reject.final.series, reject.final.interval)
        c = clamp.final.fine(ref, other, s0, ok0, clamp.final.series, clamp.final.interval)
    assert 0.1 < float(r.valid.float().mean()) < 0.9  # the truth 0.45 steps off: some pixels' best is an edge
    for a, b in zip(r, c, strict=True):
        assert torch.equal(a[r.valid.expand_as(a)], b[r.valid.expand_as(b)])
    kept = c.valid & ~r.valid
    assert kept.sum() > 0.1 * kept.numel()
    reach = 0.5 if refinement is None else 1.0  # the parabola moves <= half a step, a soft-argmin within the band
    assert float(((c.s - s0).abs() / reject.final.fine.step)[kept].max()) <= reach + 1e-5
    exact = torch.cat(series_at(clamp.final.series, c.s), 1)
    assert (c.match - exact).abs().amax(1, keepdim=True)[c.valid].max() < 1e-3


def test_similarity_reference_values():
    torch.testing.assert_close(similarity(torch.tensor([0.0, 0.25, 2.0]), "zncc", 1, 5),
                               torch.tensor([1.0, 0.75, 0.0]))
    torch.testing.assert_close(similarity(torch.tensor([12.0]), "census", 1, 5), torch.tensor([0.5]))


@pytest.mark.parametrize("radius", [1, 2])
def test_extend_estimate_fills_invalid_pixels_in_reach_with_their_valid_neighbours_mean(radius):
    gen = torch.Generator().manual_seed(6)
    s = torch.rand(2, 1, 7, 9, generator=gen, dtype=torch.float64)
    valid = torch.rand(2, 1, 7, 9, generator=gen) > 0.6
    valid[..., 5:] = False  # columns 8 (and 7 with radius 1) are out of reach
    valid[1] = False  # an image with nothing valid: nothing in reach, s unchanged
    s_nan = torch.where(valid, s, torch.full_like(s, float("nan")))  # invalid values never leak in
    out, reach = extend_estimate(s_nan, valid, radius)
    assert out.shape == s.shape and reach.dtype == torch.bool
    assert not bool(reach[0].all()) and bool((reach[0] & ~valid[0]).any())  # both cases occur
    for y, x in [(y, x) for y in range(7) for x in range(9)]:
        window = (slice(max(0, y - radius), y + radius + 1), slice(max(0, x - radius), x + radius + 1))
        neighbours = s[0, 0][window][valid[0, 0][window]]
        if valid[0, 0, y, x]:
            assert out[0, 0, y, x] == s[0, 0, y, x]
        elif neighbours.numel():
            torch.testing.assert_close(out[0, 0, y, x], neighbours.mean())
        assert bool(reach[0, 0, y, x]) == bool(neighbours.numel())
    assert not reach[1].any() and out[1].isnan().all()
    assert torch.equal(extend_estimate(s, valid, 0).s, s)
    far, far_reach = extend_estimate(s, valid, 3)
    assert far_reach.sum() >= reach.sum()
    torch.autograd.gradcheck(lambda x: extend_estimate(x, valid[:1], 1).s, (s[:1].clone().requires_grad_(),))
    with pytest.raises(OptionError, match="radius must be an int >= 0"):
        extend_estimate(s, valid, -1)
    with pytest.raises(ShapeError, match="valid must be a bool tensor"):
        extend_estimate(s, valid[:, :, :3], 1)


def test_fine_band_wide_box_blends_only_in_weak_texture(plane):
    """The wide box's weight is 1 - sigma / weak_texture: a vanishing threshold leaves the band as without it,
    a huge one replaces the box by the wide box everywhere (the same numbers as a band with that box)."""
    rig, cap = plane
    model = PrismStereo(rig, (450.0, 900.0), dict(coarse_factor=2, smoothing=0))
    ref, other = model.split(cap.image)
    s0 = torch.full((1, 1, rig.image_height, rig.reference_width), float(depth_to_sweep(
        torch.tensor(600.0), torch.tensor(model.z_range)))) + 0.01
    ok0 = torch.ones_like(s0, dtype=torch.bool)

    def band(**changes):
        band = model.final.fine
        options = band.options._replace(aggregation=dataclasses.replace(band.options.aggregation, **changes))
        fine = FineBand(options, band.band, band.step, model.final.fine.split)
        with torch.no_grad():
            return fine(ref, other, s0, ok0, model.final.series, model.final.interval)

    plain = band(wide_box=0)
    for a, b in zip(band(wide_box=21, weak_texture=1e-12), plain, strict=True):
        assert torch.equal(a, b)
    wide, boxed = band(wide_box=21, weak_texture=1e9), band(wide_box=0, fine_box=21)
    torch.testing.assert_close(wide.s, boxed.s, atol=1e-5, rtol=0)
    assert torch.equal(wide.valid, boxed.valid)
    assert model.final.fine.wide_box == 21  # the model's default


def test_fine_band_takes_the_reference_moments_it_would_compute(plane):
    """The moments a level passes (ZNCC's, and the wide box's texture) give the band's numbers bitwise, whole and
    in strips, and the texture is the grey standard deviation over the cost window."""
    rig, cap = plane
    model = PrismStereo(rig, (450.0, 900.0), dict(coarse_factor=2))
    ref, other = model.split(cap.image)
    s0 = torch.full((1, 1, rig.image_height, rig.reference_width), 0.1)
    ok0 = torch.ones_like(s0, dtype=torch.bool)
    fine, level = model.final.fine, model.final
    moments = reference_moments(ref, fine.window)
    with torch.no_grad():
        own = fine(ref, other, s0, ok0, level.series, level.interval)
        given = fine(ref, other, s0, ok0, level.series, level.interval, moments)
        fine.strip_voxels = 3 * 16 * rig.reference_width  # strips of 16 rows, each with its slice of the moments
        strips = fine(ref, other, s0, ok0, level.series, level.interval, moments)
        fine.strip_voxels = STRIP_VOXELS
    for a, b, c in zip(own, given, strips, strict=True):
        assert (a is b is c is None) or (torch.equal(a, b) and torch.equal(a, c))
    grey_ref = ref.double() - 0.5
    mean = box_filter(grey_ref, fine.window)
    std = (box_filter(grey_ref * grey_ref, fine.window) - mean * mean).sqrt()
    torch.testing.assert_close(texture_of(moments[1]).double(), std, atol=1e-5, rtol=0)


def test_guided_aggregation_carries_a_shift_through_a_flat_band_and_stops_at_edges():
    """The guided filter spreads the cost of the textured rows into a flat band of even grey between them
    (box aggregation has nothing there: every shift costs the same), and does not blend two regions of
    different grey: a left half at one shift and a right half of another grey at another keep their own. Its
    placement (final=False) keeps every winner; as a final level the ratio test still applies."""
    gen = torch.Generator().manual_seed(12)
    h, w, d = 48, 64, 12
    other = torch.rand(1, 1, h, w + d, generator=gen) * 0.5
    other[..., 18:30, :] = 0.3  # a flat band: no texture, no evidence of its own
    reference = other[..., 5:5 + w].clone()  # shift 5 everywhere
    other[..., w // 2 + 2:] = torch.rand(1, 1, h, w + d - w // 2 - 2, generator=gen) * 0.5 + 0.5  # brighter
    reference[..., w // 2:] = other[..., 2 + w // 2:2 + w]  # texture at shift 2 in the right half
    index = (torch.arange(w) + torch.arange(d).view(-1, 1)).clamp(max=w + d - 1)
    valid = torch.ones(1, d, h, w, dtype=torch.bool)
    volume = shift_cost(reference, other, index, valid, "ad_gradient")
    for aggregation, expect_band in (("guided", True), ("box", False)):
        config = resolve_level(thesis_setup1().downscaled(8), (400.0, 700.0), guided_options(aggregation))
        options = config.decision_options()
        index_w, _, confidence, unique, _ = decide(volume, options, 1, final=False, guide=to_grey(reference))
        band = index_w[0, 0, 20:28, 14:w // 2 - 14]
        assert bool((band == 5).all()) == expect_band, band
        if aggregation == "guided":
            assert bool(unique.all())  # a placement: no ratio test
            assert float((index_w[0, 0, :, 14:w // 2 - 14] == 5).float().mean()) > 0.98
            right_half = index_w[0, 0, :, w // 2 + 14:w - 3]
            assert float((right_half == 2).float().mean()) > 0.95
            assert float(confidence.min()) >= 0 and float(confidence.max()) <= 1
            _, _, _, unique_final, _ = decide(volume, options, 1, final=True, guide=to_grey(reference))
            assert not bool(unique_final.all())


def test_decide_reads_the_guided_filter_and_edge_aware_p2_options():
    """decide's aggregation is the aggregate module's under the config's options: the guided filter's radius, eps
    and subsampling, SGM's edge-aware P2 (``p2_edge``), a colour guide; the defaults are the depth model's constant
    P2 and the GUIDED_* constants."""
    from prismstereo.matching import box_filter, guided_filter, sgm_aggregate, sgm_aggregate_guided
    from prismstereo.matching.aggregate import GUIDED_EPS, GUIDED_RADIUS, GUIDED_SUBSAMPLE
    from prismstereo.matching.options import AggregationConfig

    default = AggregationConfig()
    assert default.p2_edge is None
    assert (default.guided_radius, default.guided_eps, default.guided_subsample) == (GUIDED_RADIUS, GUIDED_EPS,
                                                                                     GUIDED_SUBSAMPLE)
    gen = torch.Generator().manual_seed(5)
    volume = torch.rand(1, 6, 20, 24, generator=gen)
    guide = torch.rand(1, 3, 20, 24, generator=gen)
    guided = StereoConfig().with_options(aggregation="guided", box=3, guided_radius=4, guided_eps=1e-3,
                                         guided_subsample=1)
    total = decide(volume, guided.decision_options(), 1, final=True, guide=guide).total
    assert torch.equal(total, guided_filter(box_filter(volume, 3), guide, 4, 1e-3, 1))
    for p2_edge in (None, 0.05):
        config = StereoConfig().with_options(directions=8, p1=0.1, p2=0.9, p2_edge=p2_edge)
        total = decide(volume, config.decision_options(), 1, final=True, guide=guide).total
        local = box_filter(volume, config.aggregation.box)
        expected = (sgm_aggregate(local, 0.1, 0.9, 8) if p2_edge is None
                    else sgm_aggregate_guided(local, guide, 0.1, 0.9, 0.05, 8))
        assert torch.equal(total, expected)
    with pytest.raises(OptionError, match="edge-aware P2 .p2_edge. needs a guide image"):
        decide(volume, StereoConfig().with_options(p2_edge=0.05).decision_options(), 1, final=True)
    with pytest.raises(OptionError, match="the guided filter needs a guide image"):
        decide(volume, guided.decision_options(), 1, final=True)


def guided_options(aggregation: str) -> StereoConfig:
    """The options of a per-pixel cost aggregated by ``aggregation``."""
    return StereoConfig().with_options(cost="ad_gradient", aggregation=aggregation, box=1)
