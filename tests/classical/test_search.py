"""The classical level's whole-range search, built from its resolved options (:mod:`prismstereo.classical.search`)."""

import pytest
import torch

from prismstereo import OptionError, PrismStereo, StereoConfig, thesis_setup1
from prismstereo.classical.defaults import resolve_level
from prismstereo.classical.search import BuiltSearch, build_search
from prismstereo.epipolar.sweep import fit_sweep, sweep_coefficients
from prismstereo.matching import RectifiedSearch, SweepSearch


@pytest.fixture(scope="module")
def sweep_setup():
    rig = thesis_setup1().downscaled(8)  # 128 x 96, reference half 64 wide
    fit = fit_sweep(rig, (400.0, 900.0))
    uv = torch.stack(torch.meshgrid(torch.arange(64.0), torch.arange(96.0), indexing="xy"), -1).double()
    fine = sweep_coefficients(fit, uv).permute(2, 0, 1, 3)
    return rig, fit, fine, torch.ones(96, 64, dtype=torch.bool)


@pytest.mark.parametrize("sampling, factor, kind", [("sweep", 1, SweepSearch), ("sweep", 2, SweepSearch),
                                                    ("rectified", 2, RectifiedSearch)])
def test_build_search_gives_the_level_the_model_uses(sweep_setup, sampling, factor, kind):
    rig, fit, fine, other_valid = sweep_setup
    options = dict(num_hypotheses=30, sampling=sampling, coarse_factor=factor)
    config = resolve_level(rig, (400.0, 900.0), StereoConfig().with_options(**options))
    built = build_search(rig, fit, fine, config, other_valid)
    assert isinstance(built, BuiltSearch) and isinstance(built.search, kind)
    model = PrismStereo(rig, (400.0, 900.0), options)
    assert type(model.final.search) is kind and model.final.search.num_hypotheses == built.search.num_hypotheses
    if factor == 1:
        assert built.search.num_hypotheses == 30  # a single level keeps the requested hypotheses
    else:  # the coarse level: hypotheses <= 1 level pixel apart, fewer than the full level's
        assert 2 <= built.search.num_hypotheses < 30
    if sampling == "rectified":  # setup 1's non-central rays leave ~1e-4 px (row_rectify's measurement)
        assert 0 <= built.rectification_residual_px < 1e-3
        assert built.rectification_residual_px == model.final.rectification_residual_px
    else:
        assert built.rectification_residual_px is None


def test_build_search_rejects_an_unknown_or_unresolved_sampling(sweep_setup):
    rig, fit, fine, other_valid = sweep_setup
    config = resolve_level(rig, (400.0, 900.0), StereoConfig())
    with pytest.raises(OptionError, match="sampling.*'rectified'.*'sweep'"):
        build_search(rig, fit, fine, config.replace(search={"sampling": None}), other_valid)
