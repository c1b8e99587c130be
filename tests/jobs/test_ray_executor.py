"""RayCluster.check: an unreachable cluster fails in seconds with one line, before a model is built."""

import time

import pytest
import torch

from prismstereo.errors import PrismStereoError
from prismstereo.jobs.ray_executor import RayCluster


def test_an_unreachable_cluster_fails_fast_with_one_line(tmp_path, monkeypatch, capsys):
    ray = pytest.importorskip("ray")  # in the dev install: never skipped there
    assert not ray.is_initialized()
    monkeypatch.setenv("RAY_gcs_server_port_wait_time_s", "1")
    start = time.monotonic()
    with pytest.raises(PrismStereoError, match=r"cannot connect to the Ray cluster at 127.0.0.1:9: .*refused"):
        RayCluster("127.0.0.1:9").check()  # nothing listens: refused at once
    assert time.monotonic() - start < 5 and not ray.is_initialized()
    with pytest.raises(PrismStereoError, match=r"a Ray address is 'auto', 'local', HOST:PORT or ray://HOST:PORT"):
        RayCluster("somewhere").check()
    from prismstereo import thesis_setup1
    from prismstereo.cli import main
    from prismstereo.io import write_image
    from prismstereo.predictor import Predictor

    thesis_setup1().downscaled(8).to_json(tmp_path / "rig.json")
    write_image(tmp_path / "capture.png", torch.full((1, 96, 128), 0.5))  # never read: the address fails first

    monkeypatch.setattr(Predictor, "__init__", lambda *a, **k: pytest.fail("a model was built"))
    capsys.readouterr()
    assert main(["depth", str(tmp_path / "capture.png"), "--rig", str(tmp_path / "rig.json"), "--out",
                 str(tmp_path / "o"), "--ray", "127.0.0.1:9"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot connect to the Ray cluster" in err, err
