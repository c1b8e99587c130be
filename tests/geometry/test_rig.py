import json
import math
from pathlib import Path

import pytest
import torch

from prismstereo import BiPrismRig, RigError, load_rig, thesis_setup1, thesis_setup2
from prismstereo.geometry import check_rig_images
from prismstereo.geometry.optics import trace_pixels
from prismstereo.geometry.presets import RIG_PRESETS

CONTRACT_FIELDS = [
    "alpha_deg",
    "refractive_index",
    "focal_length_mm",
    "prism_thickness_mm",
    "apex_distance_mm",
    "pixel_size_mm",
    "image_width",
    "image_height",
    "principal_point",
    "prism_offset_x_mm",
]


def setup1_dict(**changes):
    data = {
        "alpha_deg": 6.4,
        "refractive_index": 1.48,
        "focal_length_mm": 25.0,
        "prism_thickness_mm": 5.6,
        "apex_distance_mm": 170.0,
        "pixel_size_mm": 0.00465,
        "image_width": 1024,
        "image_height": 768,
    }
    data.update(changes)
    return data


def test_setup1_values():
    rig = thesis_setup1()
    assert (rig.alpha_deg, rig.refractive_index, rig.focal_length_mm) == (6.4, 1.48, 25.0)
    assert (rig.prism_thickness_mm, rig.apex_distance_mm, rig.pixel_size_mm) == (5.6, 170.0, 0.00465)
    assert (rig.image_width, rig.image_height) == (1024, 768)
    assert rig.principal_point == (511.5, 383.5)
    assert rig.prism_offset_x_mm == 0.0 and rig.prism_tilt_deg == (0.0, 0.0, 0.0)
    assert rig.apex_column == 511.5
    # sensor width 4.7616 mm (thesis fig. 5.4) and a ~100 mm prism (b of eq. 5.16)
    assert rig.image_width * rig.pixel_size_mm == pytest.approx(4.7616)
    assert rig.prism_width_mm == pytest.approx(99.85, abs=0.01)


def test_setup2_consistent_thickness():
    rig = thesis_setup2()
    assert rig.alpha_deg == 21.8 and rig.focal_length_mm == 8.0
    assert rig.prism_thickness_mm == pytest.approx(50.0 * math.tan(math.radians(21.8)))
    assert rig.prism_thickness_mm == pytest.approx(20.0, abs=0.01)
    assert rig.prism_width_mm == pytest.approx(100.0)
    # the thesis' T = 5.6 mm would make this prism only 28 mm wide
    assert 2 * 5.6 / math.tan(math.radians(21.8)) == pytest.approx(28.0, abs=0.01)


def test_json_field_names_are_the_contract():
    data = json.loads(thesis_setup1().to_json())
    assert list(data)[: len(CONTRACT_FIELDS)] == CONTRACT_FIELDS
    assert data["principal_point"] == [511.5, 383.5]


def test_json_round_trip_file(tmp_path):
    rig = thesis_setup2().replace(prism_offset_x_mm=1.25, prism_tilt_deg=(0.5, -1.0, 0.25))
    path = tmp_path / "rig.json"
    rig.to_json(path)
    assert BiPrismRig.from_json(path) == rig
    assert BiPrismRig.from_json(str(path)) == rig
    assert BiPrismRig.from_json(rig.to_json()) == rig


def test_json_optional_fields_default():
    rig = BiPrismRig.from_dict(setup1_dict())
    assert rig == thesis_setup1()
    rig = BiPrismRig.from_dict(setup1_dict(principal_point=None))
    assert rig.principal_point == (511.5, 383.5)
    rig = BiPrismRig.from_dict(setup1_dict(principal_point=[500, 380], prism_offset_x_mm=2))
    assert rig.principal_point == (500.0, 380.0) and rig.prism_offset_x_mm == 2.0


def test_frozen():
    rig = thesis_setup1()
    with pytest.raises(AttributeError):
        rig.alpha_deg = 7.0  # type: ignore[misc]


def test_keyword_only():
    with pytest.raises(TypeError):
        BiPrismRig(6.4, 1.48, 25.0, 5.6, 170.0, 0.00465, 1024, 768)  # type: ignore[misc]


@pytest.mark.parametrize(
    "changes,match",
    [
        ({"focal_length_mm": 0.0}, "focal_length_mm must be positive"),
        ({"prism_thickness_mm": -1.0}, "prism_thickness_mm must be positive"),
        ({"apex_distance_mm": 0.0}, "apex_distance_mm must be positive"),
        ({"pixel_size_mm": -0.001}, "pixel_size_mm must be positive"),
        ({"refractive_index": 1.0}, r"refractive_index must be > 1"),
        ({"refractive_index": 0.8}, r"refractive_index must be > 1"),
        ({"alpha_deg": 0.0}, r"alpha_deg must be in \(0, 90\)"),
        ({"alpha_deg": 90.0}, r"alpha_deg must be in \(0, 90\)"),
        ({"alpha_deg": -3.0}, r"alpha_deg must be in \(0, 90\)"),
        ({"alpha_deg": float("nan")}, "alpha_deg must be a finite number"),
        ({"focal_length_mm": float("inf")}, "focal_length_mm must be a finite number"),
        ({"refractive_index": "glass"}, "refractive_index must be a finite number"),
        ({"image_width": 0}, "image size must be at least"),
        ({"image_height": 10.5}, "image_height must be an integer"),
        ({"image_width": True}, "image_width must be an integer"),
        ({"principal_point": [2000.0, 100.0]}, "principal_point .* is off the sensor"),
        ({"principal_point": [100.0, -1.0]}, "principal_point .* is off the sensor"),
        ({"principal_point": [100.0]}, "principal_point must be a list of 2"),
        ({"principal_point": "centre"}, "principal_point must be a list of 2"),
        ({"prism_tilt_deg": [50.0, 0.0, 0.0]}, r"prism_tilt_deg angles must be in \(-45, 45\)"),
        ({"prism_tilt_deg": [1.0, 2.0]}, "prism_tilt_deg must be a list of 3"),
    ],
)
def test_invalid_values(changes, match):
    with pytest.raises(RigError, match=match):
        BiPrismRig.from_dict(setup1_dict(**changes))


def _assert_geometry_rejected(rig, match):
    """Construction checks fields only; the explicit check, the validating loader and the model reject the rig."""
    from prismstereo.classical.model import PrismStereo

    with pytest.raises(RigError, match=match):
        check_rig_images(rig)
    with pytest.raises(RigError, match=match):
        load_rig(rig.to_json())
    with pytest.raises(RigError, match=match):
        load_rig(rig.to_dict())
    with pytest.raises(RigError, match=match):
        PrismStereo(rig, (400.0, 900.0))


def test_geometry_whole_half_misses_prism():
    # apex 40 mm to the right: every ray hits the left face, the right half-image sees nothing
    rig = thesis_setup1().replace(prism_offset_x_mm=40.0)  # no ray tracing in the constructor
    assert rig.prism_offset_x_mm == 40.0
    _assert_geometry_rejected(rig, "no pixel of the right half-image sees through the prism: its apex line x = 40 "
                                   r"mm \(prism_offset_x_mm\) is outside it: the field of view spans x = -16.19 to "
                                   "16.19 mm")


def test_geometry_whole_half_total_internal_reflection():
    # alpha 75 deg, n 2: inside the glass the rays meet the back plane beyond the critical angle
    rig = thesis_setup1().replace(alpha_deg=75.0, refractive_index=2.0)
    assert (rig.alpha_deg, rig.refractive_index) == (75.0, 2.0)
    _assert_geometry_rejected(rig, "no pixel of the left half-image .* totally internally reflected in the glass: a "
                                   r"smaller angle \(alpha_deg 75\) or index \(refractive_index 2\)")


def test_geometry_prism_too_far_names_the_fields():
    # 1e12 mm away the field of view is ~1e11 mm wide and the faces end 50 mm from the apex line: every ray misses
    with pytest.raises(RigError, match=r"left half-image .* its rays miss the prism, whose faces end 49.93 mm .* "
                                       r"bring the prism closer \(apex_distance_mm\), make it thicker "
                                       r"\(prism_thickness_mm\)"):
        check_rig_images(thesis_setup1().replace(apex_distance_mm=1e12))


def test_presets_pass_the_geometric_check():
    for make in RIG_PRESETS.values():
        check_rig_images(make())


def test_check_rig_images_rejects_other_types():
    with pytest.raises(RigError, match="rig must be a BiPrismRig"):
        check_rig_images(thesis_setup1().parameters())  # type: ignore[arg-type]
    with pytest.raises(RigError, match="samples must be an int >= 2"):
        check_rig_images(thesis_setup1(), samples=1)


@pytest.mark.parametrize("module", ["rig", "parameters"])
def test_rig_modules_do_not_import_optics(module):
    """rig.py and parameters.py import nothing of the ray tracer, not even inside a function (the optics build on
    them)."""
    import ast
    import importlib

    rig_module = importlib.import_module(f"prismstereo.geometry.{module}")
    tree = ast.parse(Path(rig_module.__file__).read_text())
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            imported.add(node.module or "")
            imported.update(f"{node.module}.{alias.name}" for alias in node.names)
    assert not any(name.startswith("prismstereo.geometry.optics") for name in imported), imported
    assert "prismstereo.geometry" not in imported  # the package re-exports the optics


def test_load_rig_validates(tmp_path):
    rig = thesis_setup1().replace(prism_offset_x_mm=1.5, principal_point=(500.0, 380.0))
    path = tmp_path / "rig.json"
    rig.to_json(path)
    assert load_rig(path) == rig
    assert load_rig(str(path)) == rig
    assert load_rig(rig.to_json()) == rig
    assert load_rig(rig.to_dict()) == rig
    assert load_rig("thesis_setup1") == thesis_setup1()
    bad = tmp_path / "bad.json"
    rig.replace(prism_offset_x_mm=40.0).to_json(bad)
    assert BiPrismRig.from_json(bad).prism_offset_x_mm == 40.0  # fields only
    with pytest.raises(RigError, match="no pixel of the right half-image sees through the prism"):
        load_rig(bad)
    with pytest.raises(RigError, match="rig file not found"):
        load_rig(tmp_path / "missing.json")
    with pytest.raises(RigError, match=r"unknown rig field\(s\): colour"):
        load_rig(setup1_dict(colour="red"))


@pytest.mark.parametrize(
    "text,match",
    [
        ("{not json", "not valid JSON"),
        ("[1, 2]", "must be a JSON object"),
        (json.dumps({"alpha_deg": 6.4}), "missing required field"),
        (json.dumps(setup1_dict(colour="red")), r"unknown rig field\(s\): colour"),
    ],
)
def test_bad_rig_files(tmp_path, text, match):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(RigError, match=match):
        BiPrismRig.from_json(path)


def test_missing_rig_file(tmp_path):
    with pytest.raises(RigError, match="rig file not found"):
        BiPrismRig.from_json(tmp_path / "nope.json")


def test_downscaled_keeps_the_field_of_view():
    rig = thesis_setup1().replace(principal_point=(500.0, 380.0))
    small = rig.downscaled(4)
    assert (small.image_width, small.image_height) == (256, 192)
    assert small.pixel_size_mm == pytest.approx(4 * 0.00465)
    assert small.principal_point == (127.5, 95.5)
    assert small.image_width * small.pixel_size_mm == pytest.approx(rig.image_width * rig.pixel_size_mm)
    assert rig.downscaled(1) == rig.replace(principal_point=None)
    with pytest.raises(RigError, match="factor must be a positive int"):
        rig.downscaled(0)


def test_replace_validates():
    with pytest.raises(RigError):
        thesis_setup1().replace(refractive_index=0.5)


def test_apex_column_moves_with_offset():
    rig = thesis_setup1().replace(prism_offset_x_mm=3.0)
    assert rig.apex_column == pytest.approx(511.5 + 25.0 / 0.00465 * 3.0 / 170.0)
    assert rig.reference_width == 607 == rig.parameters().reference_width  # columns u < 606.37
    assert thesis_setup1().reference_width == 512 == thesis_setup1().parameters(dtype=torch.float64).reference_width


def test_load_rig_from_preset_name_or_json_path(tmp_path):
    assert set(RIG_PRESETS) == {"thesis_setup1", "thesis_setup2"}
    assert load_rig("thesis_setup2") == thesis_setup2()
    path = tmp_path / "rig.json"
    thesis_setup1().replace(prism_offset_x_mm=1.5).to_json(path)
    assert load_rig(path).prism_offset_x_mm == 1.5
    with pytest.raises(RigError, match="rig file not found"):
        load_rig(tmp_path / "missing.json")


def test_binned_maps_pixels_exactly():
    """A k x k block's centre is full pixel k i + (k - 1) / 2: principal point and apex column map that way, and
    a scene point projects to the binned pixel of its full-resolution position."""
    rig = thesis_setup1().replace(principal_point=(500.0, 380.0), prism_offset_x_mm=0.3)
    for k in (2, 3):
        b = rig.binned(k)
        assert (b.image_width, b.image_height) == (rig.image_width // k, rig.image_height // k)
        assert b.pixel_size_mm == pytest.approx(rig.pixel_size_mm * k)
        assert b.principal_point == pytest.approx(((500.0 - (k - 1) / 2) / k, (380.0 - (k - 1) / 2) / k))
        assert b.apex_column == pytest.approx((rig.apex_column - (k - 1) / 2) / k, abs=1e-9)
        ij = torch.tensor([[3.0, 5.0], [100.0, 40.0], [b.image_width - 2.0, b.image_height - 3.0]], dtype=torch.float64)
        coarse, full = trace_pixels(b, ij), trace_pixels(rig, ij * k + (k - 1) / 2)
        torch.testing.assert_close(coarse.directions, full.directions)
        torch.testing.assert_close(coarse.origins, full.origins)
    with pytest.raises(RigError, match="positive int"):
        rig.binned(0)


def test_unbinned_is_the_finer_sensor_binning_undoes():
    rig = thesis_setup1().downscaled(2).replace(principal_point=(250.0, 190.0))
    for k in (2, 3):
        fine = rig.unbinned(k)
        assert (fine.image_width, fine.image_height) == (rig.image_width * k, rig.image_height * k)
        assert fine.binned(k).principal_point == pytest.approx(rig.principal_point)
        assert fine.binned(k).pixel_size_mm == pytest.approx(rig.pixel_size_mm)
        ij = torch.tensor([[3.0, 5.0], [100.0, 40.0]], dtype=torch.float64)  # a pixel is the finer sensor's block
        coarse, full = trace_pixels(rig, ij), trace_pixels(fine, ij * k + (k - 1) / 2)
        torch.testing.assert_close(coarse.directions, full.directions)
    with pytest.raises(RigError, match="positive int"):
        rig.unbinned(1.5)
