"""The ``prismstereo fov`` and ``prismstereo design`` subcommands."""

import pytest

from prismstereo import thesis_setup1
from prismstereo.cli import main

PNG = b"\x89PNG\r\n\x1a\n"


def test_fov_prints_type_angles_rays_and_widths(tmp_path, capsys):
    plot = tmp_path / "fov.png"
    assert main(["fov", "--rig", "thesis_setup1", "--depth-mm", "500", "1000", "--plot", str(plot)]) == 0
    out = capsys.readouterr().out
    assert "semi-divergent" in out and "alpha1 5.622 deg" in out and "alpha2 11.071 deg" in out
    assert "phi2  Ray 1 angle         0.05376 rad" in out and "+0.04053 rad" in out
    assert "left  half  Ray 1 (inner, apex)   x = +0.20344" in out
    assert "right half  Ray 2 (outer, edge)   x = +16.46734" in out
    assert "Ray 2 crosses Ray 1 at    Z = 1402.5 mm" in out
    row = next(line for line in out.splitlines() if line.strip().startswith("1000.0"))
    assert row.split()[1:3] == ["89.127", "89.127"]
    assert plot.read_bytes().startswith(PNG)


def test_fov_rig_file_convergent_and_errors(tmp_path, capsys):
    path = tmp_path / "rig.json"
    thesis_setup1().replace(alpha_deg=21.8, prism_thickness_mm=20.0).to_json(path)
    assert main(["fov", "--rig", str(path), "--depth-mm", "300", "2000"]) == 0
    out = capsys.readouterr().out
    assert "convergent" in out and "common FOV closes at      Z = " in out
    assert "none" in out  # no common FOV at 2 m
    tilted = tmp_path / "tilted.json"
    thesis_setup1().replace(prism_tilt_deg=(0.0, 2.0, 0.0)).to_json(tilted)
    assert main(["fov", "--rig", str(tilted)]) == 2
    assert "untilted" in capsys.readouterr().err
    assert main(["fov", "--depth-mm", "100"]) == 2
    assert "beyond the back plane" in capsys.readouterr().err


def test_design_one_parameter_with_plot(tmp_path, capsys):
    plot = tmp_path / "design.png"
    args = ["design", "--rig", "thesis_setup1", "--target-error-mm", "10", "--depth-mm", "1000", "--vary", "T_o",
            "--curve-depths-mm", "500", "1000", "2000", "--plot", str(plot)]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "current rig: error 10.166 mm (eq. 6.36), 9.988 mm (exact model)" in out
    assert "closed form (eq. 6.47) 172.8245 mm; exact 169.8008 mm" in out
    assert "T_o = 169.801 mm" in out and "vary focal length" not in out
    row = next(line for line in out.splitlines() if line.strip().startswith("1000.0"))
    assert "10.000" in row
    assert plot.read_bytes().startswith(PNG)


def test_design_all_parameters(capsys):
    assert main(["design", "--target-error-mm", "20", "--depth-mm", "1500"]) == 0
    out = capsys.readouterr().out
    for name in ("focal length f", "prism angle alpha", "prism distance T_o", "prism thickness T"):
        assert f"vary {name}" in out
    assert "rejected root T+" in out and "px per half-image (eq. 6.41)" in out


@pytest.mark.parametrize(
    "extra,message",
    [(["--target-error-mm", "-1", "--depth-mm", "1000"], "target_error_mm must be a positive number"),
     (["--target-error-mm", "10", "--depth-mm", "2000", "--vary", "alpha"], "no alpha reaches"),
     (["--target-error-mm", "10", "--depth-mm", "100"], "beyond the prism's back plane")],
)
def test_design_errors_exit_2(capsys, extra, message):
    assert main(["design", *extra]) == 2
    assert message in capsys.readouterr().err
