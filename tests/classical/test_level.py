"""DepthLevel: one resolution of the model (its own search or a placement from a coarser level)."""

import pytest
import torch

from prismstereo import OptionError, PrismStereo, StereoConfig, thesis_setup1
from prismstereo.classical.level import DepthLevel, Placement
from prismstereo.epipolar.sweep import depth_to_sweep
from prismstereo.synthetic import ImageFormation, fronto_parallel_plane, render

RIG = thesis_setup1().downscaled(4)  # 256 x 192
Z = (400.0, 800.0)


@pytest.fixture(scope="module")
def capture():
    return render(RIG, fronto_parallel_plane(RIG, 600.0, seed=2), ImageFormation(supersample=2, noise_sigma=1 / 255,
                                                                                 seed=4)).image


def test_a_level_with_its_own_search_finds_the_plane(capture):
    level = DepthLevel(RIG, Z, StereoConfig().with_options(coarse_factor=2))
    assert level.factor == 2 and level.band == 3 and level.config.validity.validity == "calibrated"
    assert level.config.search.sampling == "rectified" and level.search is not None
    with torch.no_grad():
        res = level.depth(capture)
    assert res.depth.shape == res.valid.shape == (1, 1, RIG.image_height, RIG.reference_width)
    assert res.match.shape == (1, 2, RIG.image_height, RIG.reference_width)
    rel = ((res.depth - 600.0).abs() / 600.0)[res.valid]
    assert res.valid.float().mean() > 0.8 and float(rel.mean()) < 2e-3


def test_the_pyramid_is_a_binned_level_placing_a_full_resolution_level(capture):
    model = PrismStereo(RIG, Z, {"downsample": 2, "full_band": 2})
    binned, final = model.levels
    assert model.binned is binned and model.final is final and final.placed_by == 2 and final.search is None
    with torch.no_grad():
        placement = binned.placement(torch.nn.functional.avg_pool2d(capture, 2))
        low = binned.depth(torch.nn.functional.avg_pool2d(capture, 2))
        res = final.depth(capture, placement)
    assert isinstance(placement, Placement) and placement.reach == 2 * binned.factor
    torch.testing.assert_close(placement.s, low.index * binned.step - 1.0)
    s_true = depth_to_sweep(torch.tensor(600.0), torch.tensor(Z))
    assert float((placement.s - s_true)[placement.valid].abs().median()) < 2 * binned.step
    assert torch.equal(res.depth, model(capture).depth)  # the model is exactly this composition


@pytest.mark.parametrize("options, binned, final, own_weights", [
    ({}, "reject", "clamp", False),  # the default: the final band clamps, the placement rejects
    ({"band_edges": "clamp"}, "clamp", "clamp", True),  # every band, with the fast setting's weights
    ({"band_edges": "reject"}, "reject", "reject", False),
    ({"dense": True}, "reject", "clamp", False),
    ({"dense": True, "band_edges": "clamp"}, "clamp", "clamp", False),
    ({"validity": "thresholds"}, "reject", "reject", False),  # NCC thresholds do not judge clamped pixels
])
def test_band_edges_resolve_per_level(options, binned, final, own_weights, capture):
    """band_edges None: a band clamps its edges where the calibrated confidence judges those pixels (the final
    band) and rejects them where thresholds do (the binned level, whose estimate only places the final band;
    ``validity='thresholds'``); an explicit rule applies to every band (a clamping one with the weights of
    :data:`~prismstereo.matching.confidence.CLAMPED_WEIGHTS`)."""
    model = PrismStereo(RIG, Z, {"downsample": 2, "full_band": 2, "coarse_factor": 2, **options})  # both with a band
    levels = (model.binned.config.search.band_edges, model.final.config.search.band_edges)
    assert levels == (model.binned.fine.band_edges, model.final.fine.band_edges) == (binned, final)
    assert (model.final.config.validity.confidence_weights == "clamped") is own_weights
    assert model.config.search.band_edges == options.get("band_edges")  # the model's config: as asked
    one = PrismStereo(RIG, Z, {"coarse_factor": 2, **options})  # one level: its only band is the final one
    assert one.final.config.search.band_edges == final


def test_the_default_clamped_band_covers_more_than_rejecting_edges(capture):
    """On a plane the clamped final band keeps pixels whose best hypothesis is on the band's edge, judged by the
    confidence: at least the coverage of 'reject', at the same accuracy."""
    truth = 600.0
    with torch.no_grad():
        default = PrismStereo(RIG, Z, {"downsample": 2, "full_band": 2})(capture)
        reject = PrismStereo(RIG, Z, {"downsample": 2, "full_band": 2, "band_edges": "reject"})(capture)
    both = default.valid & reject.valid
    assert int(default.valid.sum()) > int(reject.valid.sum()) and both.sum() == reject.valid.sum()
    def rel(r):
        return float(((r.depth - truth).abs() / truth)[r.valid].mean())

    assert rel(default) < 1.5 * rel(reject) + 1e-4, (rel(default), rel(reject))


def test_a_guided_binned_level_searching_the_whole_range_places_by_its_search_as_it_is(capture):
    """A pyramid's binned level with coarse_factor 1 and the guided aggregation passes its search's estimate
    unsmoothed and without the similarity threshold: s, and valid where the search had a real winner; its depth()
    output (smoothed, thresholded) is stricter. (The semi-global one places by its depth():
    test_the_pyramid_is_a_binned_level_placing_a_full_resolution_level.)"""
    options = {"cost": "ad_gradient", "aggregation": "guided", "box": 1}
    model = PrismStereo(RIG, Z, {"downsample": 2, "full_band": 2, "coarse_factor": 1, **options})
    binned = model.binned
    assert binned.factor == 1
    image = torch.nn.functional.avg_pool2d(capture, 2)
    with torch.no_grad():
        placement = binned.placement(image)
        raw = binned.search(*binned.split(image), final=False)
        low = binned.depth(image)
    assert placement.reach == 2 * binned.config.search.coarse_reach
    torch.testing.assert_close(placement.s, raw.s.clamp(-1.0, 1.0))
    assert torch.equal(placement.valid, raw.valid & binned.reference_valid)
    torch.testing.assert_close(placement.similarity, raw.confidence * placement.valid)
    assert float(placement.valid.float().mean()) > float(low.valid.float().mean())
    s_true = depth_to_sweep(torch.tensor(600.0), torch.tensor(Z))
    assert float((placement.s - s_true)[placement.valid].abs().median()) < binned.step
    with torch.no_grad():
        res = model(capture)
    rel = ((res.depth - 600.0).abs() / 600.0)[res.valid]
    assert res.valid.float().mean() > 0.75 and float(rel.mean()) < 1e-3  # measured 78.6 % (the field of view)


@pytest.mark.parametrize("options", [{"fine_cost": "ad_gradient"}, {"cost": "ad_gradient", "aggregation": "guided",
                                                                    "box": 1, "sampling": "sweep"}],
                         ids=["fine-band", "sweep-guided"])
def test_the_ad_gradient_cost_serves_any_level(capture, options):
    """'ad_gradient' is one of the costs: as the fine band's (its gradients along each band slice's rows) and on
    the exact-sweep coarse level with the guided filter, the plane comes out within 0.1 % (median)."""
    level = DepthLevel(RIG, Z, StereoConfig().with_options(coarse_factor=2, validity="thresholds", **options))
    with torch.no_grad():
        res = level.depth(capture)
    rel = ((res.depth - 600.0).abs() / 600.0)[res.valid]
    assert res.valid.float().mean() > 0.65 and float(rel.median()) < 1e-3  # measured 72.6 / 78.8 %, 0.06 / 0.04 %


def test_level_errors(capture):
    with pytest.raises(OptionError, match="validity 'calibrated' needs a coarse-to-fine model"):
        DepthLevel(RIG, Z, StereoConfig().with_options(coarse_factor=1, validity="calibrated"))
    with pytest.raises(OptionError, match="dense needs a coarse-to-fine model"):
        DepthLevel(RIG, Z, StereoConfig().with_options(coarse_factor=1, dense=True))
    with pytest.raises(OptionError, match="coarse_factor must be an int >= 1 leaving >= 8 rows"):
        DepthLevel(RIG, Z, StereoConfig().with_options(coarse_factor=32))
    level = DepthLevel(RIG, Z, StereoConfig().with_options(coarse_factor=2))
    with pytest.raises(OptionError, match="a placed level needs the coarser level's result"):
        level.depth(capture, Placement(torch.zeros(1, 1, 96, 64), torch.ones(1, 1, 96, 64, dtype=torch.bool),
                                       torch.ones(1, 1, 96, 64), 2))
