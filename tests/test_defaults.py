"""The rules behind PrismStereo's defaults (prismstereo.defaults)."""

import dataclasses

from prismstereo import thesis_setup1, thesis_setup2
from prismstereo.defaults import default_coarse_factor, default_downsample, pyramid_band, pyramid_coarse_factor
from prismstereo.model import PrismStereo


def test_default_downsample_switches_at_384_px():
    rig = thesis_setup1()  # 1024 x 768: reference half 512 x 768
    assert default_downsample(rig) == default_downsample(thesis_setup2()) == 2
    assert default_downsample(rig.downscaled(2)) == 1  # 256 x 384 reference half: 256 < 384
    short = dataclasses.replace(rig, image_height=383, principal_point=(rig.principal_point[0], 191.0))
    assert default_downsample(short) == 1  # the shorter side of the reference half is the height now
    assert PrismStereo.default_downsample(rig) == 2  # the model's static method is the same rule


def test_default_coarse_factor_thresholds():
    # f doubles while the coarse level keeps >= 24 hypotheses (D / 2f) and >= 32 px per side (min / 2f), up to 4
    assert default_coarse_factor(368, 768, 512) == 4
    assert default_coarse_factor(96, 768, 512) == 4  # 96 / 4 = 24 hypotheses at f = 4
    assert default_coarse_factor(95, 768, 512) == 2  # 95 / 4 < 24
    assert default_coarse_factor(47, 768, 512) == 1  # 47 / 2 < 24: one level
    assert default_coarse_factor(368, 127, 512) == 2  # 127 / 4 < 32 rows at f = 4
    assert default_coarse_factor(368, 128, 512) == 4
    assert default_coarse_factor(10_000, 4096, 4096) == 4  # never beyond 4
    assert PrismStereo.default_coarse_factor(382, 768, 512) == default_coarse_factor(382, 768, 512)


def test_pyramid_band_and_the_models_binned_band():
    assert [pyramid_band(f) for f in (2, 3, 4, 8)] == [2, 3, 3, 6]
    model = PrismStereo(thesis_setup1(), (228.0, 1374.0))  # the default pyramid
    assert model.binned is not None and model.binned.band == pyramid_band(model.binned.factor) == 3
    own = PrismStereo(thesis_setup1(), (228.0, 1374.0), dict(band=5))  # an explicit band is kept
    assert own.binned.band == 5


def test_pyramid_coarse_factor_leaves_12_hypotheses():
    """A pyramid's binned model only places the final band: >= 12 coarse hypotheses instead of 24, so the narrow
    range (600-1450 mm: 52 / 94 binned hypotheses with setups 1 / 2) gets f = 4 where a model of its own gets 2;
    the wide range and an explicit coarse_factor keep theirs."""
    assert [pyramid_coarse_factor(d, 384, 256) for d in (52, 48, 47, 24, 23, 94, 222)] == [4, 4, 2, 2, 1, 4, 4]
    assert default_coarse_factor(52, 384, 256) == default_coarse_factor(94, 384, 256) == 2
    assert pyramid_coarse_factor(222, 127, 256) == 2  # >= 32 rows as before
    narrow = PrismStereo(thesis_setup1(), (600.0, 1450.0))
    assert narrow.binned.num_hypotheses == 52 and narrow.binned.factor == 4 and narrow.binned.band == 3
    assert PrismStereo(thesis_setup1(), (600.0, 1450.0), dict(coarse_factor=2)).binned.factor == 2
    assert PrismStereo(narrow.rig, narrow.z_range, narrow.config()).binned.factor == 4  # the config round trip keeps it
