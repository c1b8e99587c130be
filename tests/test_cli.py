import json
import subprocess
import sys

import pytest

from prismstereo import BiPrismRig, __version__, thesis_setup1
from prismstereo.cli import main


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"prismstereo {__version__}"


def test_console_script_installed():
    out = subprocess.run([sys.executable, "-m", "prismstereo.cli", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and __version__ in out.stdout


def test_rig_show_file(tmp_path, capsys):
    path = tmp_path / "rig.json"
    thesis_setup1().replace(prism_offset_x_mm=2.0).to_json(path)
    assert main(["rig", "show", str(path)]) == 0
    out = capsys.readouterr().out
    assert "prism_offset_x_mm    2.0" in out
    for half in ("left", "right"):
        for method in ("two-point", "least-squares"):
            assert f"{half} virtual camera ({method})" in out
    assert "non-centrality (mm)" in out and "pinhole error (px)" in out


def test_rig_show_preset(capsys):
    assert main(["rig", "show", "thesis_setup1"]) == 0
    out = capsys.readouterr().out
    assert "beta (rad)              +0.05376" in out
    assert "beta (rad)              -0.05376" in out
    assert "centre C (mm)           [-9.1714" in out


def test_rig_preset_writes_json(tmp_path, capsys):
    path = tmp_path / "setup2.json"
    assert main(["rig", "preset", "thesis_setup2", "--out", str(path)]) == 0
    assert BiPrismRig.from_json(path).alpha_deg == 21.8
    assert main(["rig", "preset", "thesis_setup1"]) == 0
    assert json.loads(capsys.readouterr().out.split("\n", 1)[1])["alpha_deg"] == 6.4


@pytest.mark.parametrize(
    "content,message",
    [(None, "rig file not found"), ("{oops", "not valid JSON"), ('{"alpha_deg": 6.4}', "missing required field")],
)
def test_rig_show_bad_files(tmp_path, capsys, content, message):
    path = tmp_path / "rig.json"
    if content is not None:
        path.write_text(content)
    assert main(["rig", "show", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("prismstereo: error:") and message in err


def test_no_command_prints_help(capsys):
    assert main([]) == 2
    assert "usage: prismstereo" in capsys.readouterr().err


def test_demo(capsys):
    assert main(["demo"]) == 0
    out = capsys.readouterr().out
    assert "left virtual camera (least-squares)" in out
    lines = [ln for ln in out.splitlines() if ln.strip().startswith("depth")]
    assert len(lines) == 4
    for line in lines:  # the exact round trip is far below a micro-pixel
        assert float(line.split("max error")[1].split("px")[0]) < 1e-6
