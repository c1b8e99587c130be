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
    (["--rig", "thesis_setup1", "--out", "w.pt", "--start", "learned"], "--start applies to --model hybrid only"),
    (["--model", "start", "--rig", "thesis_setup1", "--out", "w.pt"], "--rig apply to --model learned only (the start"),
    (["--model", "head", "--z-range", "400", "900", "--out", "w.pt"],
     "--z-range apply to --model learned only (the head trains on the rig variants"),
    (["--model", "hybrid", "--weights", "h.pt", "--out", "w.pt"], "--weights applies to --model head only"),
    (["--model", "head", "--weights", "w.missing", "--out", "w.pt", "--steps", "1"], "w.missing"),
])
def test_cli_train_errors(tmp_path, capsys, args, message):
    args = [str(tmp_path / a) if a.startswith("w.") else a for a in args]
    assert main(["train", *args, "--quiet"]) == 2
    assert message in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(("model", "function"), [("start", "train_start"), ("hybrid", "train_hybrid")])
def test_cli_trains_the_hybrid_and_its_first_stage_with_their_options(tmp_path, monkeypatch, capsys, model, function):
    """The flags reach the trainer (its renders are tested in tests/learned: seven 1024 x 768 rig variants here would
    take minutes)."""
    import torch

    import prismstereo.learned.confidence_train as confidence_train
    import prismstereo.learned.hybrid_train as hybrid_train
    import prismstereo.learned.start_train as start_train
    from prismstereo.learned.train import TrainResult

    seen = {}

    def fake(out, **options):
        seen.update(options)
        return TrainResult(torch.zeros(3), 1.0, out)

    head = {}

    def fake_head(weights, **options):  # the hybrid's confidence head, trained after its refinement
        head.update(options, weights=weights)
        return TrainResult(torch.full((4,), 0.25), 1.0, weights)

    monkeypatch.setattr(start_train if model == "start" else hybrid_train, function, fake)
    monkeypatch.setattr(confidence_train, "train_exact_confidence", fake_head)
    extra = ["--start", "learned"] if model == "hybrid" else []
    out = tmp_path / "w.pt"
    assert main(["train", "--model", model, "--out", str(out), "--steps", "7", "--captures", "3", "--seed", "5",
                 "--cache", str(tmp_path), "--quiet", *extra]) == 0
    assert (seen["steps"], seen["captures"], seen["cache"], seen["progress"]) == (7, 3, str(tmp_path), False)
    assert seen["batch_size"] == (2 if model == "start" else 8)
    printed = capsys.readouterr().out
    if model == "hybrid":
        assert seen["architecture"].start == "learned"
        assert head == {"weights": out, "seed": 5, "captures": 3, "cache": str(tmp_path), "progress": False}
        assert "confidence head: 4 steps in 1 s, loss 0.250" in printed
    else:
        assert not head
    assert "trained 3 steps" in printed


def test_cli_trains_only_the_confidence_head(tmp_path, monkeypatch, capsys):
    """--model head: the hybrid weights given (default: the shipped ones) and the flags reach the head's trainer."""
    import torch

    import prismstereo.learned.confidence_train as confidence_train
    from prismstereo.learned import HYBRID_WEIGHTS
    from prismstereo.learned.train import TrainResult

    seen = []

    def fake(weights, out, **options):
        seen.append((weights, out, options))
        return TrainResult(torch.zeros(5), 2.0, out)

    monkeypatch.setattr(confidence_train, "train_exact_confidence", fake)
    out = tmp_path / "w.pt"
    assert main(["train", "--model", "head", "--out", str(out), "--quiet", "--cache", str(tmp_path)]) == 0
    assert main(["train", "--model", "head", "--weights", str(tmp_path / "h.pt"), "--out", str(out), "--steps", "9",
                 "--seed", "2", "--captures", "4", "--batch-size", "3", "--quiet"]) == 0
    assert seen[0][:2] == (HYBRID_WEIGHTS, out) and seen[0][2] == {
        "steps": 1500, "seed": 0, "batch_size": 4, "captures": 24, "cache": str(tmp_path), "progress": False}
    assert seen[1][0] == str(tmp_path / "h.pt") and seen[1][2] == {
        "steps": 9, "seed": 2, "batch_size": 3, "captures": 4, "cache": None, "progress": False}
    assert "trained 5 steps" in capsys.readouterr().out
