"""``prismstereo train``: the learned model's trainer from the command line, and its errors (the hybrid's:
``tests/learned/test_hybrid.py``)."""

import pytest

from prismstereo import thesis_setup1
from prismstereo.cli import main
from prismstereo.learned import load_weights

pytestmark = pytest.mark.usefixtures("one_thread")


def test_cli_train(tmp_path, capsys):
    rig = thesis_setup1().downscaled(8)
    rig_file = tmp_path / "rig.json"
    rig.to_json(rig_file)
    out = tmp_path / "w.pt"
    code = main(["train", "--rig", str(rig_file), "--out", str(out), "--steps", "2", "--captures", "2",
                 "--downscale", "1", "--hypotheses", "8", "--batch-size", "1", "--cache", str(tmp_path), "--quiet"])
    assert code == 0 and out.is_file()
    assert "wrote" in capsys.readouterr().out
    assert load_weights(out)[2]["rig"] == "rig"


@pytest.mark.parametrize(("args", "message"), [
    (["--rig", "no_such_rig", "--out", "w.pt"], "no_such_rig"),
    (["--rig", "thesis_setup1", "--out", "w.onnx"], "must be a .pt file"),
    (["--rig", "thesis_setup1", "--out", "w.pt", "--z-range", "900", "400"], "increasing"),
])
def test_cli_train_errors(tmp_path, capsys, args, message):
    args = [str(tmp_path / a) if a.startswith("w.") else a for a in args]
    assert main(["train", *args, "--quiet"]) == 2
    assert message in capsys.readouterr().err
    assert not list(tmp_path.iterdir())
