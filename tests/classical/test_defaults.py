"""The rules behind PrismStereo's defaults and the one function that applies them (prismstereo.classical.defaults)."""

import dataclasses

import pytest
import torch

from prismstereo import OptionError, PrismStereo, StereoConfig, preset, thesis_setup1, thesis_setup2
from prismstereo.classical.defaults import (
    ResolvedConfig,
    default_coarse_factor,
    default_downsample,
    default_hypotheses,
    pyramid_band,
    pyramid_coarse_factor,
    resolve_config,
    resolve_level,
)
from prismstereo.epipolar.sweep import fit_sweep, sweep_coefficients, sweep_hypotheses
from prismstereo.matching.confidence import FITTED_PLACEMENT

SMALL, Z = thesis_setup1().downscaled(4), (400.0, 800.0)  # 256 x 192: coarse-to-fine at full resolution


def test_default_downsample_switches_at_384_px():
    rig = thesis_setup1()  # 1024 x 768: reference half 512 x 768
    assert default_downsample(rig) == default_downsample(thesis_setup2()) == 2
    assert default_downsample(rig.downscaled(2)) == 1  # 256 x 384 reference half: 256 < 384
    short = dataclasses.replace(rig, image_height=383, principal_point=(rig.principal_point[0], 191.0))
    assert default_downsample(short) == 1  # the shorter side of the reference half is the height now


def test_default_coarse_factor_thresholds():
    # f doubles while the coarse level keeps >= 24 hypotheses (D / 2f) and >= 32 px per side (min / 2f), up to 4
    assert default_coarse_factor(368, 768, 512) == 4
    assert default_coarse_factor(96, 768, 512) == 4  # 96 / 4 = 24 hypotheses at f = 4
    assert default_coarse_factor(95, 768, 512) == 2  # 95 / 4 < 24
    assert default_coarse_factor(47, 768, 512) == 1  # 47 / 2 < 24: one level
    assert default_coarse_factor(368, 127, 512) == 2  # 127 / 4 < 32 rows at f = 4
    assert default_coarse_factor(368, 128, 512) == 4
    assert default_coarse_factor(10_000, 4096, 4096) == 4  # never beyond 4


@pytest.mark.parametrize("rig", [thesis_setup1().downscaled(4), thesis_setup2().downscaled(2)], ids=["s1", "s2"])
def test_default_hypotheses_are_the_sweeps_probed_on_its_pixels(rig):
    """D from the probed pixels only is the D of the sweep on every pixel (which probes the same ones)."""
    fit = fit_sweep(rig, Z)
    uv = torch.stack(torch.meshgrid(torch.arange(rig.reference_width, dtype=torch.float64),
                                    torch.arange(rig.image_height, dtype=torch.float64), indexing="xy"), -1)
    fine = sweep_coefficients(fit, uv).permute(2, 0, 1, 3)
    assert default_hypotheses(rig, Z) == sweep_hypotheses(fine) == sweep_hypotheses(fine[:, ::4, ::4], stride=1)
    assert default_hypotheses(rig, list(Z)) == default_hypotheses(rig, Z)  # any sequence of two depths


def test_pyramid_band_and_coarse_factor_of_the_binned_level():
    """A pyramid's binned level only places the final band: >= 12 coarse hypotheses instead of 24, so the narrow
    range (600-1450 mm: 52 binned hypotheses with setup 1) gets f = 4 where a level of its own gets 2, and a band of
    ceil(3 f / 4) instead of f + 1; an explicit coarse factor or band is kept."""
    assert [pyramid_band(f) for f in (2, 3, 4, 8)] == [2, 3, 3, 6]
    assert [pyramid_coarse_factor(d, 384, 256) for d in (52, 48, 47, 24, 23, 94, 222)] == [4, 4, 2, 2, 1, 4, 4]
    assert default_coarse_factor(52, 384, 256) == default_coarse_factor(94, 384, 256) == 2
    assert pyramid_coarse_factor(222, 127, 256) == 2  # >= 32 rows as before
    binned, final = resolve_config(thesis_setup1(), (600.0, 1450.0), StereoConfig()).levels
    assert (binned.search.num_hypotheses, binned.search.coarse_factor, binned.search.band) == (52, 4, 3)
    assert (final.search.coarse_factor, final.search.band) == (2, 2)  # placed by the 2 x 2-binned level
    wide = resolve_config(thesis_setup1(), (228.0, 1374.0), StereoConfig()).levels[0].search
    assert wide.band == pyramid_band(wide.coarse_factor) == 3
    own = resolve_config(thesis_setup1(), (600.0, 1450.0), StereoConfig().with_options(coarse_factor=2, band=5))
    assert (own.levels[0].search.coarse_factor, own.levels[0].search.band) == (2, 5)


def test_resolve_config_sets_every_option_by_its_rule():
    resolved = resolve_config(thesis_setup1(), Z, StereoConfig())
    assert isinstance(resolved, ResolvedConfig) and resolved.z_range_mm == Z
    assert (resolved.downsample, resolved.full_band) == (2, 2) and len(resolved.levels) == 2
    binned, final = resolved.levels
    # the binned level places the band: thresholds with the placement the confidence was fitted with, no wide box
    assert binned.validity.validity == "thresholds" and not binned.validity.dense
    assert {k: getattr(binned.validity, k) for k in FITTED_PLACEMENT} == FITTED_PLACEMENT
    assert binned.aggregation.wide_box == 0 and binned.search.band_edges == "reject"
    assert binned.search.sampling == final.search.sampling == "rectified"
    # the final level: calibrated, its band clamps, the weights fitted on bands asked to reject (the default)
    assert final.validity.validity == "calibrated" and final.search.band_edges == "clamp"
    assert final.validity.confidence_weights == "default" and final.refinement.refinement == "parabola"
    assert final.search.num_hypotheses == default_hypotheses(thesis_setup1(), Z)
    # the model-wide config asked for, with downsample and full_band set, rebuilds the same levels
    assert resolved.config.search.num_hypotheses is None
    assert resolve_config(thesis_setup1(), Z, resolved.config) == resolved
    # a level already resolved stays as it is
    assert resolve_level(thesis_setup1(), Z, final, placed_by=2) == final
    single = resolve_config(SMALL, None, StereoConfig())  # the rig's default range
    assert single.downsample == 1 and single.full_band == 0 and len(single.levels) == 1
    assert single.z_range_mm == PrismStereo(SMALL).z_range


@pytest.mark.parametrize("options, rules", [
    ({}, {"validity": "calibrated", "band_edges": "clamp", "confidence_weights": "default", "sampling": "rectified",
          "refinement": "parabola", "min_uniqueness": FITTED_PLACEMENT["min_uniqueness"]}),
    ({"coarse_factor": 1}, {"validity": "thresholds", "band_edges": "reject", "sampling": "sweep"}),
    ({"coarse_factor": 1, "min_uniqueness": 0.5}, {"min_uniqueness": 0.5}),  # thresholds keep the option
    ({"coarse_factor": 2, "min_uniqueness": 0.5}, {"min_uniqueness": FITTED_PLACEMENT["min_uniqueness"]}),
    ({"band_edges": "clamp"}, {"band_edges": "clamp", "confidence_weights": "clamped"}),
    ({"band_edges": "clamp", "dense": True}, {"confidence_weights": "default"}),  # fitted with the defaults
    ({"dense": True}, {"band_edges": "clamp"}),
    ({"validity": "thresholds"}, {"band_edges": "reject"}),
    ({"fine_cost": "census"}, {"refinement": "equiangular"}),
    ({"coarse_factor": 1, "cost": "sad"}, {"refinement": "equiangular"}),
    ({"refinement": "soft_argmin"}, {"refinement": "soft_argmin"}),
    ({"confidence_weights": "clamped"}, {"band_edges": "clamp", "confidence_weights": "clamped"}),
])
def test_resolve_level_rules(options, rules):
    """Each rule of resolve_level, on a coarse-to-fine level (coarse_factor 2) unless the options say otherwise."""
    level = resolve_level(SMALL, Z, StereoConfig().with_options(**{"coarse_factor": 2, **options}))
    for name, value in rules.items():
        assert level.to_options()[name] == value, name


def test_resolve_errors_name_the_option():
    with pytest.raises(OptionError, match="downsample must be an int >= 1 leaving >= 16 rows, got 16"):
        resolve_config(SMALL, Z, StereoConfig().with_options(downsample=16))
    with pytest.raises(OptionError, match="full_band must be an int >= 0, and > 0 only with downsample > 1"):
        resolve_config(SMALL, Z, StereoConfig().with_options(full_band=1))
    with pytest.raises(OptionError, match="coarse_factor must be an int >= 1 leaving >= 8 rows, got 32"):
        resolve_level(SMALL, Z, StereoConfig().with_options(coarse_factor=32))
    with pytest.raises(OptionError, match="validity 'calibrated' needs a coarse-to-fine model"):
        resolve_level(SMALL, Z, StereoConfig().with_options(coarse_factor=1, validity="calibrated"))
    with pytest.raises(OptionError, match="dense needs a coarse-to-fine model"):
        resolve_level(SMALL, Z, preset("dense").with_options(coarse_factor=1))
    with pytest.raises(OptionError, match="config must be a StereoConfig, got dict"):
        resolve_config(SMALL, Z, {"coarse_factor": 2})
    with pytest.raises(OptionError, match="confidence_weights 'fitted'"):
        StereoConfig().with_options(confidence_weights="fitted")
