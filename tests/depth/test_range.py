import math

import pytest
import torch

from prismstereo import thesis_setup1, thesis_setup2
from prismstereo.analysis import fov_closed_form
from prismstereo.depth import DepthRangeError, back_plane_depth, check_z_range, covisible_fraction, default_z_range

F64 = torch.float64


pytestmark = pytest.mark.usefixtures("one_thread")


def convergent_rig():
    """Setup 1 with a 14 deg prism (> alpha_2 = 11.07 deg): the common FOV closes (thesis Table 5.1)."""
    return thesis_setup1().replace(alpha_deg=14.0, prism_thickness_mm=12.0)


def test_covisible_fraction_follows_the_common_fov():
    rig = thesis_setup1()
    fov = fov_closed_form(rig)
    z = torch.tensor([180.0, 228.0, 400.0, 800.0, float(fov.crossing_depth), 3000.0], dtype=F64)
    c = covisible_fraction(rig, z)
    assert c.shape == (6,) and c.dtype == F64
    assert (c[:5].diff() > 0).all()  # grows as the two halves' views overlap
    assert c[4] == 1.0  # both halves see the same region where Ray 2 crosses Ray 1 (1402 mm)
    assert 0.85 < c[5] < 1.0  # semi-divergent: shrinks slowly beyond
    # the pixel share matches the common-FOV share of the reference half's width (centre row, top view)
    from prismstereo.analysis import exact_fov_extent

    ext = exact_fov_extent(rig, z[:4])
    share = ext.width / (ext.left[:, 1] - ext.left[:, 0])
    torch.testing.assert_close(c[:4], share, atol=0.04, rtol=0)
    # a coarser sensor with the same FOV gives the same fractions
    torch.testing.assert_close(covisible_fraction(rig.downscaled(8), z), c)


@pytest.mark.parametrize("make,expected", [(thesis_setup1, (222.1, 1332.6)), (thesis_setup2, (214.6, 1287.7))])
def test_default_z_range_values(make, expected):
    rig = make()
    z_min, z_max = default_z_range(rig)
    assert z_min == pytest.approx(expected[0], abs=0.1) and z_max == pytest.approx(expected[1], abs=0.5)
    assert z_max == pytest.approx(6 * z_min)  # the ratio rule; the thesis' 228-1374 mm has ratio 6.03
    below, at = covisible_fraction(rig, [z_min * (1 - 1e-5), z_min])
    assert below < 0.25 <= at  # z_min is the first depth where a quarter of the reference view is co-visible


def test_default_z_range_options_and_scale():
    rig = thesis_setup1()
    z_min, z_max = default_z_range(rig.downscaled(8))
    assert (z_min, z_max) == pytest.approx((222.1, 1332.6), abs=0.5)  # scale-free: same FOV, same range
    z0, z1 = default_z_range(rig, min_covisible=0.5, depth_ratio=3.0)
    assert z0 > z_min and z1 == pytest.approx(3 * z0)
    assert covisible_fraction(rig, z0) >= 0.5 > covisible_fraction(rig, z0 * (1 - 1e-5))


def test_default_z_range_cut_where_a_convergent_fov_narrows():
    rig = convergent_rig()
    assert fov_closed_form(rig).fov_type == "convergent"
    z_min, z_max = default_z_range(rig)
    assert z_max < 6 * z_min
    c = covisible_fraction(rig, [z_min, 0.5 * (z_min + z_max), z_max * (1 - 1e-6), z_max * 1.001])
    assert (c[:3] >= 0.25).all() and c[3] < 0.25


def test_default_z_range_errors():
    rig = thesis_setup1()
    with pytest.raises(DepthRangeError, match="min_covisible must lie in"):
        default_z_range(rig, min_covisible=0.0)
    with pytest.raises(DepthRangeError, match="depth_ratio must be"):
        default_z_range(rig, depth_ratio=1.0)
    with pytest.raises(DepthRangeError, match="never share 100% of the reference view"):
        default_z_range(convergent_rig(), min_covisible=1.0)


def test_check_z_range():
    rig = thesis_setup1()
    assert check_z_range(rig, (250, 1000)) == (250.0, 1000.0)
    assert back_plane_depth(rig) == pytest.approx(175.6)
    cases = [
        ((500.0, 400.0), r"z_max \(400 mm\) must be greater than z_min \(500 mm\)"),
        ((500.0, 500.0), "must be greater than z_min"),
        ((100.0, 500.0), "z_min 100 mm is not beyond the prism's back plane at Z = 175.6 mm"),
        ((175.6, 500.0), "not beyond the prism's back plane"),
        ((200.0, math.inf), "must be finite"),
        (("a", 300.0), "must be two numbers"),
    ]
    for z_range, message in cases:
        with pytest.raises(DepthRangeError, match=message):
            check_z_range(rig, z_range)
    spans = r"no common field of view at Z = 1000 mm \(it spans Z = 182\.0-7\d\d\.\d mm\)"
    with pytest.raises(DepthRangeError, match=spans):
        check_z_range(convergent_rig(), (300.0, 1000.0))


def test_check_z_range_before_the_common_fov():
    # a prism turned 5 deg about y: just beyond T_o + T no reference pixel is co-visible yet
    rig = thesis_setup1().replace(prism_tilt_deg=(0.0, 5.0, 0.0))
    z_min = back_plane_depth(rig) + 0.01
    assert covisible_fraction(rig, z_min) == 0
    with pytest.raises(DepthRangeError, match="z_min 175.61 mm is before the common field of view of the two halves, "
                                              r"which starts at Z = 175\.\d mm"):
        check_z_range(rig, (z_min, 500.0))
