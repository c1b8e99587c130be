"""Point -> pixel projection through the prism (:mod:`prismstereo.geometry.projection`): round trips with the
tracer on the thesis rigs and random rigs, batch shapes, invalid points, argument errors, gradients."""

import math

import pytest
import torch
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from prismstereo.errors import OptionError, PrismStereoError, RigError, ShapeError
from prismstereo.geometry.optics import points_at_depth, trace_pixels
from prismstereo.geometry.presets import thesis_setup1, thesis_setup2
from prismstereo.geometry.projection import project_points, solve_projection
from tests.conftest import ROUND_TRIP_TOL, random_pixels
from tests.geometry.test_optics import misaligned_rig, params_fn

F64 = torch.float64


def test_project_points_round_trip(rig, dtype):
    uv = random_pixels(rig, 3000, dtype, seed=2)
    rays = trace_pixels(rig, uv)
    for depth in (rays.origins[:, 2] + 0.5, 250.0, 1000.0, 5000.0):  # 0.5 mm beyond the (tilted) back plane
        pts = points_at_depth(rays, depth)
        for half, mask in (("left", rays.left), ("right", ~rays.left)):
            m = mask & rays.valid
            proj = project_points(rig, pts[m], half)
            assert proj.uv.dtype == dtype
            err = (proj.uv - uv[m]).norm(dim=-1)
            assert err.max().item() < ROUND_TRIP_TOL[dtype], (half, depth)
            assert proj.valid.all(), (half, depth)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    alpha=st.floats(2.0, 25.0),
    n=st.floats(1.4, 1.8),
    f=st.floats(8.0, 35.0),
    t_o=st.floats(60.0, 300.0),
    d=st.floats(-3.0, 3.0),
    tilt=st.tuples(st.floats(-2.0, 2.0), st.floats(-2.0, 2.0), st.floats(-2.0, 2.0)),
    depth=st.floats(1.0, 5000.0),
    seed=st.integers(0, 2**16),
)
def test_project_points_round_trip_random_rigs(alpha, n, f, t_o, d, tilt, depth, seed):
    try:
        rig = thesis_setup1().replace(
            alpha_deg=alpha, refractive_index=n, focal_length_mm=f, apex_distance_mm=t_o,
            prism_thickness_mm=50.0 * math.tan(math.radians(alpha)), prism_offset_x_mm=d, prism_tilt_deg=tilt,
        )
    except RigError:
        assume(False)
    uv = random_pixels(rig, 64, F64, seed=seed)
    rays = trace_pixels(rig, uv)
    assume(bool(rays.valid.any()))
    z = torch.maximum(rays.origins[:, 2] + 1.0, torch.tensor(depth, dtype=F64))
    pts = points_at_depth(rays, z)
    for half, mask in (("left", rays.left), ("right", ~rays.left)):
        m = mask & rays.valid
        if m.any():
            proj = project_points(rig, pts[m], half)
            assert (proj.uv - uv[m]).norm(dim=-1).max().item() < 1e-6
            assert proj.valid.all()


def test_project_points_batch_dims(dtype):
    rig = thesis_setup1()
    gen = torch.Generator().manual_seed(3)
    pts = torch.rand(2, 3, 5, 3, generator=gen, dtype=dtype) * torch.tensor([40.0, 40.0, 800.0], dtype=dtype)
    pts = pts + torch.tensor([-20.0, -20.0, 400.0], dtype=dtype)
    proj = project_points(rig, pts, "left")
    assert proj.uv.shape == (2, 3, 5, 2) and proj.valid.shape == (2, 3, 5)
    flat = project_points(rig, pts.reshape(-1, 3), "left")
    torch.testing.assert_close(proj.uv.reshape(-1, 2), flat.uv)


def test_project_points_invalid_points():
    rig = thesis_setup1()
    pts = torch.tensor(
        [
            [0.0, 0.0, 100.0],  # between camera and prism
            [0.0, 0.0, 175.0],  # inside the glass (before the back plane at 175.6)
            [-600.0, 0.0, 600.0],  # far outside the field of view
            [0.0, 0.0, 600.0],  # on the axis: seen by both halves
        ],
        dtype=F64,
    )
    left = project_points(rig, pts, "left")
    right = project_points(rig, pts, "right")
    assert left.valid.tolist() == [False, False, False, True]
    assert right.valid.tolist() == [False, False, False, True]
    assert torch.isfinite(left.uv).all() and torch.isfinite(right.uv).all()
    # the on-axis point: left half sees it at u < apex column, right half at u > apex column
    assert left.uv[3, 0] < rig.apex_column < right.uv[3, 0]
    torch.testing.assert_close(left.uv[3, 0] + right.uv[3, 0], torch.tensor(2 * rig.cx, dtype=F64))


def test_project_points_bad_arguments():
    rig = thesis_setup1()
    with pytest.raises(ShapeError, match=r"points must have shape \(\*, 3\)"):
        project_points(rig, torch.zeros(4, 2), "left")
    with pytest.raises(OptionError, match="Unknown half 'auto'. Choose from: 'left', 'right'"):
        project_points(rig, torch.zeros(4, 3), "auto")
    with pytest.raises(RigError, match="iterations must be a positive int"):
        project_points(rig, torch.zeros(4, 3), "left", iterations=0)
    with pytest.raises(PrismStereoError, match="floating-point"):
        project_points(rig, torch.zeros(4, 3, dtype=torch.int32), "left")



@pytest.mark.parametrize("make", [thesis_setup1, misaligned_rig])
def test_gradcheck_project_wrt_rig(make):
    rig = make()
    pts = torch.tensor([[10.0, 5.0, 600.0], [-40.0, -20.0, 900.0]], dtype=F64)
    for half in ("left", "right"):
        fn, inputs = params_fn(rig, lambda p, h=half: project_points(p, pts, h).uv)
        assert torch.autograd.gradcheck(fn, inputs)


def test_solve_projection_final_step_alone_from_converged_pixels():
    # iterations=0: the differentiable step only, from pixels converged for these points (the calibration's
    # Jacobian): the same pixels and the same implicit-function gradient as the full solve
    rig = misaligned_rig()
    pts = torch.tensor([[10.0, 5.0, 600.0], [-40.0, -20.0, 900.0]], dtype=F64, requires_grad=True)
    full = solve_projection(rig, pts, "right")
    alone = solve_projection(rig, pts, "right", iterations=0, initial_uv=full.uv.detach())
    torch.testing.assert_close(alone.uv, full.uv, rtol=0.0, atol=1e-9)
    assert torch.equal(alone.valid, full.valid) and full.valid[0]
    g_full, = torch.autograd.grad(full.uv.sum(), pts)
    g_alone, = torch.autograd.grad(alone.uv.sum(), pts)
    torch.testing.assert_close(g_alone, g_full, rtol=1e-6, atol=1e-9)
    with pytest.raises(RigError, match="iterations must be an int >= 0"):
        solve_projection(rig, pts, "right", iterations=-1)


def test_gradcheck_project_wrt_points():
    rig = thesis_setup2()
    pts = torch.tensor([[10.0, 5.0, 600.0], [-40.0, -20.0, 300.0]], dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: project_points(rig, x, "left").uv, (pts,))
