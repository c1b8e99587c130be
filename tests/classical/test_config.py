import functools
import json

import numpy as np
import pytest
import torch

from prismstereo import PRESETS, OptionError, PrismStereo, StereoConfig, preset, thesis_setup1
from prismstereo.classical.config import as_config
from prismstereo.classical.defaults import resolve_config
from prismstereo.cli import main

RIG = thesis_setup1().downscaled(2)  # 512 x 384: coarse-to-fine by default (the dense output needs it)
Z = (400.0, 900.0)


@functools.cache
def _preset_model(name: str) -> PrismStereo:
    """The model of a preset, by its name, built once for the module's tests (0.5-0.9 s each on this sensor; the
    tests only read it and run it). The module's tests run on one xdist worker (tests/conftest.py: XDIST_GROUPS)."""
    return PrismStereo(RIG, Z, name)


# A model's resolved options (``model.resolved``) are ``resolve_config(rig, z_range, as_config(config))`` of what it
# was built with: another form of the same config is compared with a built model through resolve_config, without
# building a model of each form.


def test_default_config_is_the_models_default():
    default = PrismStereo(RIG, Z).resolved
    assert as_config(None) == as_config("accurate") == StereoConfig()
    assert _preset_model("accurate").resolved == resolve_config(RIG, Z, StereoConfig()) == default
    # every option of every level is set (None only where it means "off")
    for level in default.levels:
        unset = {k for k, v in level.to_options().items() if v is None}
        assert unset <= {"lr_threshold", "occlusion_tolerance", "occluder_confidence", "p2_edge"}, unset


@pytest.mark.parametrize("name", list(PRESETS))
def test_presets_build_the_model_of_their_options_and_round_trip(name, tmp_path):
    model = _preset_model(name)
    assert model.resolved == resolve_config(RIG, Z, preset(name))
    flat = StereoConfig().with_options(**model.config.to_options())  # the flat options are a config too
    assert resolve_config(RIG, model.z_range, flat) == model.resolved
    preset(name).to_json(tmp_path / "c.json")
    assert StereoConfig.from_json(tmp_path / "c.json") == preset(name)


def test_presets_differ_where_they_say():
    assert _preset_model("dense").final.config.validity.dense
    fast = _preset_model("fast")
    assert fast.downsample == 2 and fast.binned is not None and fast.final.band == 1
    assert fast.final.config.search.band_edges == "clamp"
    reference = _preset_model("reference")
    assert reference.final.factor == 1 and reference.binned is None and reference.downsample == 1
    image = torch.rand(1, 1, 384, 512, generator=torch.Generator().manual_seed(0))
    assert fast(image).depth.shape == (1, 1, 384, RIG.reference_width)


def test_config_errors(tmp_path):
    with pytest.raises(OptionError, match="unknown preset 'quick'. Choose from: accurate, fast, dense, reference"):
        preset("quick")
    with pytest.raises(OptionError, match="unknown option 'zoom'; valid: .*band_edges"):
        StereoConfig().with_options(zoom=2)
    with pytest.raises(OptionError, match="unknown config group 'speed'; valid: search, cost"):
        StereoConfig().replace(speed={})
    with pytest.raises(OptionError, match="config group 'search': .*unexpected keyword argument 'zoom'"):
        StereoConfig().replace(search={"zoom": 1})
    with pytest.raises(OptionError, match="config group 'search' must be an object of options"):
        StereoConfig.from_dict({"search": 3})
    with pytest.raises(OptionError, match="a config must be a JSON object of groups"):
        StereoConfig.from_dict([1])
    with pytest.raises(OptionError, match="cannot read the config"):
        StereoConfig.from_json(tmp_path / "missing.json")
    with pytest.raises(OptionError, match="config must be a StereoConfig, a preset name or a dict of options"):
        PrismStereo(RIG, Z, 3)
    with pytest.raises(OptionError, match="band_edges"):  # values are checked by the model
        PrismStereo(RIG, Z, StereoConfig().replace(search={"band_edges": "wrap"}))


def test_cli_preset_and_config(tmp_path, capsys):
    from prismstereo import synthetic as syn
    from prismstereo.io import write_image

    rig = thesis_setup1().downscaled(8)
    rig.to_json(tmp_path / "rig.json")
    cap = syn.render(rig, [syn.fronto_parallel_plane(rig, 600.0, seed=3)], syn.ImageFormation(noise_sigma=1 / 255))
    write_image(tmp_path / "c.png", cap.image[0])
    base = ["depth", str(tmp_path / "c.png"), "--rig", str(tmp_path / "rig.json"), "--z-range", "400", "900"]
    assert main([*base, "--out", str(tmp_path / "d.npy"), "--preset", "fast"]) == 0
    assert "2x2-binned model" in capsys.readouterr().out
    assert main([*base, "--out", str(tmp_path / "x.npy"), "--preset", "dense"]) == 0  # its coarse factor 2
    assert (tmp_path / "x_confidence.npy").exists()
    capsys.readouterr()
    (tmp_path / "single.json").write_text(json.dumps({"validity": {"dense": True}, "search": {"coarse_factor": 1}}))
    assert main([*base, "--out", str(tmp_path / "y.npy"), "--config", str(tmp_path / "single.json")]) == 2
    assert "dense needs a coarse-to-fine model" in capsys.readouterr().err
    config = {"validity": {"dense": True}, "search": {"num_hypotheses": 30, "coarse_factor": 2}}
    (tmp_path / "cfg.json").write_text(json.dumps(config))
    assert main([*base, "--out", str(tmp_path / "e.npy"), "--config", str(tmp_path / "cfg.json")]) == 0
    out = capsys.readouterr().out
    assert "30 hypotheses" in out and (tmp_path / "e_confidence.npy").exists()  # a dense config: as --dense
    assert np.isfinite(np.load(tmp_path / "e.npy")).mean() > 0.5
    both = ["--preset", "fast", "--config", str(tmp_path / "cfg.json")]
    assert main([*base, "--out", str(tmp_path / "f.npy"), *both]) == 2
    assert "--preset and --config exclude each other" in capsys.readouterr().err
    (tmp_path / "bad.json").write_text('{"search": {"zoom": 1}}')
    assert main([*base, "--out", str(tmp_path / "g.npy"), "--config", str(tmp_path / "bad.json")]) == 2
    assert "unexpected keyword argument 'zoom'" in capsys.readouterr().err


def test_model_takes_a_config_a_preset_or_a_dict_only():
    """One constructor, PrismStereo(rig, z_range_mm, config): no keyword options, no other positional forms."""
    small, z = thesis_setup1().downscaled(8), (400.0, 700.0)
    by_dict = PrismStereo(small, z, {"coarse_factor": 2, "smoothing": 0})
    by_config = PrismStereo(small, z, StereoConfig().with_options(coarse_factor=2, smoothing=0))
    assert by_dict.resolved == by_config.resolved and by_dict.final.factor == 2
    assert preset("fast").with_options(smoothing=0).to_options() == {**preset("fast").to_options(), "smoothing": 0}
    with pytest.raises(TypeError, match="unexpected keyword argument 'coarse_factor'"):
        PrismStereo(small, z, coarse_factor=2)
    with pytest.raises(OptionError, match="config must be a StereoConfig, a preset name or a dict of options"):
        PrismStereo(small, z, 20)
    with pytest.raises(OptionError, match="unknown option 'zoom'"):
        PrismStereo(small, z, {"zoom": 2})
    with pytest.raises(OptionError, match="unknown preset 'quick'"):
        PrismStereo(small, z, "quick")


@pytest.mark.parametrize(("group", "options", "message"), [
    ("cost", {"window": 4}, "window must be a positive odd int"),
    ("cost", {"cost": "ssd"}, "cost"),
    ("aggregation", {"wide_box": 2}, "wide_box must be 0 .off. or a positive odd int"),
    ("aggregation", {"directions": 3}, "directions must be 2, 4 or 8"),
    ("aggregation", {"p1": 9.0}, "p2 must be a finite number >= p1 .9.0."),
    ("aggregation", {"p2_edge": 0.0}, "p2_edge must be a finite number > 0 or None"),
    ("aggregation", {"guided_radius": 0}, "guided_radius must be an int >= 1"),
    ("aggregation", {"guided_eps": -1.0}, "guided_eps must be a finite number > 0"),
    ("aggregation", {"guided_subsample": 0}, "guided_subsample must be an int >= 1"),
    ("refinement", {"smoothing": 1}, "smoothing must be 0 .off. or an odd int >= 3"),
    ("refinement", {"smoothing_tolerance": float("inf")}, "smoothing_tolerance must be a finite number > 0"),
    ("validity", {"dense": 1}, "dense must be a bool"),
    ("validity", {"reach_confidence": 1.5}, "reach_confidence must be in \\[0, 1\\]"),
    ("search", {"num_hypotheses": 1}, "num_hypotheses must be an int >= 2 or None"),
    ("search", {"lr_threshold": 0}, "lr_threshold must be > 0 or None"),
])
def test_config_groups_check_their_values(group, options, message):
    with pytest.raises(OptionError, match=message):
        StereoConfig().replace(**{group: options})


def test_help_of_the_model_is_short():
    """The model's own documentation fits a screen or two; the options are documented by the config groups."""
    import pydoc

    text = pydoc.render_doc(PrismStereo, renderer=pydoc.plaintext)
    own = text.split("Methods inherited from")[0]
    assert len(own.splitlines()) < 200, len(own.splitlines())
    assert "smoothing_tolerance" in pydoc.render_doc(StereoConfig.__init__.__globals__["RefinementConfig"],
                                                     renderer=pydoc.plaintext)
