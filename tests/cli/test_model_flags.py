"""The model flags of ``prismstereo depth`` and ``export`` (:mod:`prismstereo.cli.model_flags`): which model they
ask for, and their errors named by the flags."""

import pytest

from prismstereo import PrismStereoError, thesis_setup1
from prismstereo.cli import build_parser
from prismstereo.cli.model_flags import model_spec
from prismstereo.learned import HYBRID_WEIGHTS


def test_which_model_the_flags_ask_for(tmp_path):
    """--model; else the classical model with a preset, a config or a search option, the hybrid with --weights,
    else the rig's default (the hybrid from 512 x 384 up); options of another model refused."""
    large, small = thesis_setup1(), thesis_setup1().downscaled(4)
    weights = str(HYBRID_WEIGHTS)
    (tmp_path / "c.json").write_text('{"search": {"coarse_factor": 2}}')

    def spec(*flags, rig=large):
        args = build_parser().parse_args(["depth", "x.png", "--rig", "r", "--out", "o", *flags])
        return model_spec(args, rig)

    assert spec().resolved_kind == "hybrid" and spec(rig=small).resolved_kind == "classical"
    assert spec("--dense").resolved_kind == "hybrid" and spec("--weights", weights, rig=small).resolved_kind == "hybrid"
    for flags in (["--preset", "dense"], ["--config", str(tmp_path / "c.json")], ["--hypotheses", "9"],
                  ["--downsample", "2"], ["--full-band", "1"], ["--band-edges", "clamp"]):
        assert spec(*flags).resolved_kind == "classical"
    assert spec("--config", str(tmp_path / "c.json")).config.search.coarse_factor == 2
    assert spec("--preset", "fast", "--dense").config.validity.dense
    for model in ("hybrid", "classical", "learned"):
        assert spec("--model", model, rig=small).resolved_kind == model
    learned = spec("--model", "learned", "--hypotheses", "9")
    assert learned.resolved_kind == "learned" and learned.config == {"num_hypotheses": 9}
    with pytest.raises(PrismStereoError, match="--preset set the classical model's options, not --model learned's"):
        spec("--model", "learned", "--preset", "fast")
    with pytest.raises(PrismStereoError, match="--weights is the hybrid's or the learned model's, not the classical"):
        spec("--weights", weights, "--downsample", "2")
    with pytest.raises(PrismStereoError, match="--weights is the hybrid's"):
        spec("--weights", weights, "--model", "classical")
    last = spec("--last-stage", "learned", rig=small)  # the hybrid, on any sensor
    assert last.resolved_kind == "hybrid" and last.config == {"last_stage": "learned"}
    with pytest.raises(PrismStereoError, match="--last-stage is the hybrid's, not the learned model's"):
        spec("--model", "learned", "--last-stage", "exact")
    with pytest.raises(PrismStereoError, match="--last-stage is the hybrid's, not the classical model's"):
        spec("--preset", "fast", "--last-stage", "exact")
    with pytest.raises(PrismStereoError, match="--preset and --config exclude each other"):
        spec("--preset", "fast", "--config", str(tmp_path / "c.json"))
    with pytest.raises(PrismStereoError, match="--hypotheses must be an int >= 2"):
        spec("--model", "learned", "--hypotheses", "1")
    with pytest.raises(PrismStereoError, match="--full-band must be an int >= 0"):
        spec("--full-band", "-1")
    with pytest.raises(PrismStereoError, match="weights file .*missing.pt does not exist"):
        spec("--weights", str(tmp_path / "missing.pt"))


def test_request_flags_name_files_by_content_and_keys_follow_them(tmp_path):
    """The flags as the cache's index remembers them: a file flag by its content (an edited rig is another
    request), a preset by its name; the temporal binning only when sequences are tracked; the key changes with any
    of them and is the same for the same flags."""
    from prismstereo.cli.model_flags import request_flags
    from prismstereo.export.index import flags_key

    rig = tmp_path / "rig.json"
    rig.write_text('{"a": 1}')
    args = _parse("--rig", str(rig), "--z-range", "400", "700")
    flags = request_flags(args, tracked=False)
    assert flags["rig"].startswith("sha256:") and flags["temporal"] is None and flags["z_range"] == [400.0, 700.0]
    assert request_flags(args, tracked=True)["temporal"] == {"binning": None}
    key = flags_key(flags)
    assert key.startswith("flags-") and flags_key(request_flags(args, tracked=False)) == key
    rig.write_text('{"a": 2}')
    assert flags_key(request_flags(args, tracked=False)) != key
    assert request_flags(_parse("--rig", "thesis_setup1"), tracked=False)["rig"] == "thesis_setup1"
    assert flags_key(request_flags(_parse("--rig", "thesis_setup1", "--dense"), tracked=False)) != flags_key(
        request_flags(_parse("--rig", "thesis_setup1"), tracked=False))


def _parse(*flags):
    return build_parser().parse_args(["depth", "x.png", "--out", "o", *flags])
