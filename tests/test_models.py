"""One way to a depth model (:mod:`prismstereo.models`): the interface every model satisfies, the spec, the builder,
the rig's default, and the one grey rule every model follows."""

import pytest
import torch

from prismstereo import OptionError, thesis_setup1, thesis_setup2
from prismstereo.classical import PrismStereo, TemporalOptions
from prismstereo.conventions import to_grey
from prismstereo.learned import HYBRID_WEIGHTS, HybridStereo, LearnedStereo, WeightsError
from prismstereo.models import HYBRID_MIN_SIDE, DepthModel, ModelSpec, build_model, default_kind, describe_model

SMALL = thesis_setup1().downscaled(8)  # 128 x 96
Z = (400.0, 700.0)


def test_default_kind_is_the_hybrid_from_512_x_384():
    kinds = [default_kind(thesis_setup1().downscaled(k)) for k in (1, 2, 4, 8)]
    assert kinds == ["hybrid", "hybrid", "classical", "classical"]
    assert default_kind(thesis_setup2()) == "hybrid"
    # the rule's edge: the reference half's shorter side, and a sensor the first stage's cells divide (4 x 4 pixels
    # where the stages run at full resolution, 8 x 8 where they run 2 x 2-binned)
    rig = thesis_setup1().downscaled(2)
    side = min(rig.image_height, rig.reference_width)
    assert side >= HYBRID_MIN_SIDE > thesis_setup1().downscaled(4).reference_width
    assert default_kind(rig.replace(image_width=510, principal_point=(254.5, 191.5))) == "classical"
    assert default_kind(rig.replace(image_width=516, principal_point=(257.5, 191.5))) == "hybrid"
    assert default_kind(thesis_setup1().replace(image_width=1028, principal_point=(513.5, 383.5))) == "classical"
    assert default_kind(thesis_setup1().replace(image_width=1032, principal_point=(515.5, 383.5))) == "hybrid"


@pytest.fixture(scope="module")
def models():
    torch.manual_seed(0)
    return {"classical": build_model(SMALL, "classical", Z, {"coarse_factor": 2}),
            "hybrid": build_model(SMALL, "hybrid", Z),
            "learned": build_model(SMALL, "learned", Z, {"num_hypotheses": 12})}


def test_every_model_is_a_depth_model_with_one_interface(models):
    """kind, rig, one name for the range (z_range), describe / summary, a DepthResult of the reference half, the
    tracker it offers for video (the learned model none), eval mode."""
    types = {"classical": PrismStereo, "hybrid": HybridStereo, "learned": LearnedStereo}
    image = torch.rand(1, 1, 96, 128, generator=torch.Generator().manual_seed(1))
    for kind, model in models.items():
        assert isinstance(model, DepthModel) and type(model) is types[kind] and model.kind == kind
        assert model.rig == SMALL and tuple(model.z_range) == Z and not model.training
        assert model.describe()["z_range_mm"] == list(Z) and isinstance(model.summary(), str)
        with torch.inference_mode():
            out = model(image)
        assert out.depth.shape == (1, 1, 96, 64) and out.valid.dtype == torch.bool
    assert type(models["classical"].tracker()).__name__ == "TemporalDepth"
    assert models["learned"].tracker() is None
    assert models["hybrid"].tracker() is None  # its band is the classical default's: one level on this small rig
    assert not isinstance(torch.nn.Identity(), DepthModel)


def test_one_grey_rule_colour_and_its_grey_give_the_same_depth(models):
    """Every model converts colour by to_grey (BT.601) at its entry: a colour capture and its grey give the same
    outputs, bit for bit."""
    colour = torch.rand(2, 3, 96, 128, generator=torch.Generator().manual_seed(2))
    for kind, model in models.items():
        with torch.inference_mode():
            a, b = model(colour), model(to_grey(colour))
        for name, x, y in zip(a._fields, a, b, strict=True):
            assert torch.equal(x.nan_to_num(), y.nan_to_num()), (kind, name)


def test_build_model_and_spec_pick_the_kind_and_refuse_options_of_another_model(tmp_path):
    assert ModelSpec(rig=thesis_setup1()).resolved_kind == "hybrid"
    assert ModelSpec(rig=SMALL).resolved_kind == "classical"
    assert ModelSpec(rig=thesis_setup1(), config="fast").resolved_kind == "classical"
    assert build_model(SMALL, z_range=Z, config="fast").config.search.full_band == 1
    with pytest.raises(OptionError, match="Unknown kind 'sgbm'"):
        ModelSpec(rig=SMALL, kind="sgbm")
    with pytest.raises(OptionError, match="weights are the hybrid's or the learned model's"):
        ModelSpec(rig=SMALL, kind="classical", weights=HYBRID_WEIGHTS)
    with pytest.raises(OptionError, match="the hybrid model's config is a dict of last_stage, got 'fast'"):
        ModelSpec(rig=SMALL, kind="hybrid", config="fast")
    assert build_model(SMALL, "hybrid", Z, {"last_stage": "learned"}).exact is None
    with pytest.raises(OptionError, match="Unknown last_stage 'band'. Choose from: 'exact', 'learned'"):
        build_model(SMALL, "hybrid", Z, {"last_stage": "band"})
    with pytest.raises(OptionError, match="the learned model's config is a dict of num_hypotheses"):
        ModelSpec(rig=SMALL, kind="learned", config={"coarse_factor": 2})
    with pytest.raises(WeightsError, match="does not exist"):
        ModelSpec(rig=SMALL, kind="hybrid", weights=tmp_path / "none.pt")
    with pytest.raises(OptionError, match="rig must be a BiPrismRig"):
        ModelSpec(rig="thesis_setup1")


def test_spec_request_is_what_was_asked_before_the_rig_resolves_it(tmp_path):
    """The cache's key: the kind, range and options as asked (a classical config as its dict, a weights file by its
    content); two specs of the same request have the same one."""
    spec = ModelSpec(rig=SMALL, z_range=Z, config={"coarse_factor": 2})
    request = spec.request()
    assert request["kind"] == "classical" and request["z_range_mm"] == list(Z)
    assert request["config"]["search"]["coarse_factor"] == 2 and request["weights"] == "default"
    assert ModelSpec(rig=SMALL, z_range=Z, config={"coarse_factor": 2}).request() == request
    copy = tmp_path / "copy.pt"
    copy.write_bytes(HYBRID_WEIGHTS.read_bytes())
    a = ModelSpec(rig=SMALL, kind="hybrid", weights=HYBRID_WEIGHTS).request()
    assert a == ModelSpec(rig=SMALL, kind="hybrid", weights=copy).request() and len(a["weights"]) == 64


def test_describe_model_says_how_videos_are_tracked(models):
    classical = models["classical"]
    assert describe_model(classical) == classical.summary()
    tracker = classical.tracker(TemporalOptions(band=2))
    line = describe_model(classical, TemporalOptions(band=2), tracker)
    assert line.endswith("temporal prior on sequences (a band +-2 around the previous depth between key frames)")
    assert "every frame on its own" in describe_model(models["learned"], TemporalOptions(), None)
    hybrid = describe_model(models["hybrid"], TemporalOptions(), tracker)  # a band of another model
    assert "; tracked between key frames by the classical model (" in hybrid
