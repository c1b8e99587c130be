"""Virtual cameras of the two half-images (thesis chapter 3), as Kornia pinhole cameras.

Each half-image sees the scene through one face of the prism, as if from a second camera: a *virtual
camera*. The thesis builds it from ray geometry (sec. 3.2): the optical centre is where back-extended
outgoing rays meet, the orientation is the outgoing apex ray, the focal length follows eq. 3.13-3.17.
These cameras are only an approximation: the back-extended rays do not meet in one point (non-centrality)
and the prism distorts anamorphically, so every camera returned here carries its measured non-centrality
(mm) and pinhole reprojection error (px) against the exact ray tracer of :mod:`prismstereo.geometry.optics`.

Frames: the virtual camera's pixel coordinates are the real sensor's (u, v) (so ``camera.project`` gives
the approximate pixel of a scene point in the full image); its extrinsics map the real camera frame to the
virtual camera frame, X_vc = R^T (X - C); ``rotation`` R holds the virtual camera's axes as columns.
``beta`` is the rotation about y (positive turns +z toward +x): the left half's virtual camera sits at
x < 0 and looks toward +x (beta > 0). The thesis' Fig. 3.4 frame has the opposite sign of beta and of
OC_x (it quotes the left virtual camera at x = +9.167 mm, rotated by -0.0538 rad); magnitudes agree.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal, NamedTuple

import torch

from prismstereo.errors import OptionError, RigError, check_option, check_shape
from prismstereo.geometry.optics import Half, RayBundle, apex_ray, points_at_depth, trace_pixels
from prismstereo.geometry.rig import BiPrismRig

if TYPE_CHECKING:
    from kornia.geometry.camera import PinholeCamera

__all__ = [
    "VirtualCamera",
    "VirtualCameraPair",
    "Method",
    "ray_midpoint",
    "closest_point_to_rays",
    "virtual_camera",
    "virtual_cameras",
    "pinhole_reprojection_error",
]

Method = Literal["two_point", "least_squares"]
_METHODS = ("two_point", "least_squares")


class VirtualCamera(NamedTuple):
    """A half-image's virtual pinhole camera and how well a pinhole describes it.

    Attributes:
        camera: kornia ``PinholeCamera`` (batch 1, float64), pixel coordinates of the full sensor.
        centre: (3,) optical centre C in the real camera frame (mm).
        rotation: (3, 3) virtual camera axes as columns (camera-to-real-frame rotation).
        focal_length_mm: () mean of fx, fy times the pixel size.
        beta: () rotation about y (rad), atan2(R[0, 2], R[2, 2]).
        noncentrality_max_mm: () largest distance of a back-extended ray of the half to ``centre``.
        noncentrality_rms_mm: () RMS of those distances.
        reprojection_error_mean_px: () mean pinhole reprojection error of exact correspondences.
        reprojection_error_max_px: () max of that error.
        half: 'left' or 'right'.
        method: 'two_point' or 'least_squares'.
    """

    camera: PinholeCamera
    centre: torch.Tensor
    rotation: torch.Tensor
    focal_length_mm: torch.Tensor
    beta: torch.Tensor
    noncentrality_max_mm: torch.Tensor
    noncentrality_rms_mm: torch.Tensor
    reprojection_error_mean_px: torch.Tensor
    reprojection_error_max_px: torch.Tensor
    half: str
    method: str


class VirtualCameraPair(NamedTuple):
    """The left (reference) and right virtual cameras."""

    left: VirtualCamera
    right: VirtualCamera


def ray_midpoint(
    origin1: torch.Tensor, direction1: torch.Tensor, origin2: torch.Tensor, direction2: torch.Tensor
) -> torch.Tensor:
    """Midpoint of the common perpendicular of two lines (the thesis' mid-point theorem, Appendix C).

    Args:
        origin1, direction1, origin2, direction2: (*, 3) points on and directions of the two lines.

    Returns:
        (*, 3) midpoint. Parallel lines give non-finite values.

    Example:
        >>> o1, d1 = torch.tensor([0., 0., 0.]), torch.tensor([1., 0., 0.])
        >>> o2, d2 = torch.tensor([0., 1., 2.]), torch.tensor([0., 0., 1.])
        >>> ray_midpoint(o1, d1, o2, d2)
        tensor([0.0000, 0.5000, 0.0000])
    """
    for name, t in (("origin1", origin1), ("direction1", direction1), ("origin2", origin2), ("direction2", direction2)):
        check_shape(t, ["*", 3], name)
    w0 = origin1 - origin2
    a = (direction1 * direction1).sum(-1)
    b = (direction1 * direction2).sum(-1)
    c = (direction2 * direction2).sum(-1)
    d = (direction1 * w0).sum(-1)
    e = (direction2 * w0).sum(-1)
    den = a * c - b * b
    s = ((b * e - c * d) / den).unsqueeze(-1)
    t = ((a * e - b * d) / den).unsqueeze(-1)
    return 0.5 * (origin1 + s * direction1 + origin2 + t * direction2)


def closest_point_to_rays(origins: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
    """The point minimising the sum of squared distances to N lines (all-pixel virtual centre).

    Solves sum_i (I - d_i d_i^T) C = sum_i (I - d_i d_i^T) o_i, the least-squares generalisation of the
    thesis' two-ray midpoint (sec. 3.3.2, fig. 3.13-3.17, which averages per-pixel intersections instead).

    Args:
        origins: (*, N, 3) points on the lines.
        directions: (*, N, 3) unit directions.

    Returns:
        (*, 3) the least-squares centre.

    Example:
        >>> o = torch.tensor([[1., 0., 0.], [0., 1., 0.]]); d = torch.tensor([[-1., 0., 1.], [0., -1., 1.]])
        >>> closest_point_to_rays(o, torch.nn.functional.normalize(d, dim=-1)).round(decimals=4)
        tensor([0., 0., 1.])
    """
    check_shape(origins, ["*", "N", 3], "origins")
    check_shape(directions, ["*", "N", 3], "directions")
    eye = torch.eye(3, dtype=directions.dtype, device=directions.device)
    proj = eye - directions.unsqueeze(-1) * directions.unsqueeze(-2)  # (*, N, 3, 3)
    lhs = proj.sum(-3)
    rhs = (proj @ origins.unsqueeze(-1)).sum(-3)
    return torch.linalg.solve(lhs, rhs).squeeze(-1)


def _half_grid(rig: BiPrismRig, half: Half, step: int) -> tuple[torch.Tensor, RayBundle]:
    """Pixels on a regular grid of the half with valid rays, and their rays (float64)."""
    # linspace over the whole sensor: mirror-symmetric about the image centre, with an even column count so
    # no sample sits on the centre column (which would go to the left half only)
    nu = -(-(rig.image_width - 1) // step) + 1
    u = torch.linspace(0.0, rig.image_width - 1.0, nu + nu % 2, dtype=torch.float64)
    v = torch.linspace(0.0, rig.image_height - 1.0, -(-(rig.image_height - 1) // step) + 1, dtype=torch.float64)
    uv = torch.stack(torch.meshgrid(u, v, indexing="xy"), dim=-1).reshape(-1, 2)
    rays = trace_pixels(rig, uv)
    keep = rays.valid & (rays.left if half == "left" else ~rays.left)
    if int(keep.sum()) < 8:
        raise RigError(f"fewer than 8 valid grid pixels in the {half} half (grid step {step} px); use a smaller step")
    return uv[keep], RayBundle(*(t[keep] for t in rays))


def _line_distances(rays: RayBundle, point: torch.Tensor) -> torch.Tensor:
    rel = point - rays.origins
    along = (rel * rays.directions).sum(-1, keepdim=True)
    return (rel - along * rays.directions).norm(dim=-1)


def _axes_from_direction(axis: torch.Tensor) -> torch.Tensor:
    """Rotation whose z column is ``axis`` and whose y column is the camera's y made orthogonal."""
    ey = torch.tensor([0.0, 1.0, 0.0], dtype=axis.dtype)
    y = ey - (ey @ axis) * axis
    y = y / y.norm()
    x = torch.linalg.cross(y, axis)
    return torch.stack([x, y, axis], dim=1)


def _rodrigues(w: torch.Tensor) -> torch.Tensor:
    theta = w.norm().clamp_min(1e-12)
    k = w / theta
    zero = torch.zeros_like(k[0])
    kx = torch.stack([zero, -k[2], k[1], k[2], zero, -k[0], -k[1], k[0], zero]).view(3, 3)
    return torch.eye(3, dtype=w.dtype) + torch.sin(theta) * kx + (1 - torch.cos(theta)) * kx @ kx


def _camera(fx, fy, cx, cy, rotation, centre, rig: BiPrismRig) -> PinholeCamera:
    # kornia imported where used: a cached graph's depth run never loads it
    from kornia.geometry.camera import PinholeCamera

    dt = rotation.dtype
    k = torch.eye(4, dtype=dt)
    k[0, 0], k[1, 1], k[0, 2], k[1, 2] = fx, fy, cx, cy
    e = torch.eye(4, dtype=dt)
    e[:3, :3] = rotation.T
    e[:3, 3] = -rotation.T @ centre
    height = torch.tensor([float(rig.image_height)], dtype=dt)
    width = torch.tensor([float(rig.image_width)], dtype=dt)
    return PinholeCamera(k[None], e[None], height, width)


def _samples(rig: BiPrismRig, half: Half, step: int, depth_range_mm: tuple[float, float], depths: int):
    """Exact correspondences: grid pixels and the points they see at depths uniform in inverse depth."""
    z0, z1 = depth_range_mm
    back = rig.apex_distance_mm + rig.prism_thickness_mm
    if not back < z0 < z1:
        raise RigError(f"depth_range_mm must satisfy back plane ({back:.1f} mm) < z_min < z_max, got {depth_range_mm}")
    uv, rays = _half_grid(rig, half, step)
    inv = torch.linspace(1.0 / z0, 1.0 / z1, depths, dtype=torch.float64)
    pts = torch.stack([points_at_depth(rays, 1.0 / iz) for iz in inv])  # (D, N, 3)
    return uv, rays, pts


def pinhole_reprojection_error(
    rig: BiPrismRig,
    camera: PinholeCamera,
    half: Half,
    depth_range_mm: tuple[float, float] = (250.0, 1500.0),
    grid_step: int = 16,
    depths: int = 8,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and max pixel error of a pinhole camera against the exact prism model.

    Points seen by a grid of the half's pixels at ``depths`` depths (uniform in inverse depth over
    ``depth_range_mm``) are projected with ``camera`` (kornia) and compared with their true pixels.

    Args:
        rig: the rig.
        camera: kornia PinholeCamera (batch 1), e.g. ``virtual_camera(...).camera``.
        half: the half the camera models.
        depth_range_mm: (z_min, z_max) beyond the back plane.
        grid_step: pixel grid spacing.
        depths: number of depth samples.

    Returns:
        (mean, max) 0-d float64 tensors, px.

    Example:
        >>> vc = virtual_camera(thesis_setup1(), "left")
        >>> mean, worst = pinhole_reprojection_error(thesis_setup1(), vc.camera, "left")
        >>> bool(worst < 5.0)
        True
    """
    check_option(half, ("left", "right"), "half")
    uv, _, pts = _samples(rig, half, grid_step, depth_range_mm, depths)
    proj = camera.project(pts.reshape(-1, 3).to(camera.intrinsics.dtype)).reshape(pts.shape[0], -1, 2)
    err = (proj - uv.to(proj.dtype)).norm(dim=-1)
    return err.mean(), err.max()


def _two_point(rig: BiPrismRig, half: Half, pixels: torch.Tensor | None, focal_pixel: torch.Tensor | None):
    sign = -1.0 if half == "left" else 1.0
    ac, cy = rig.apex_column, rig.cy
    if pixels is None:  # two points near the image centre, as the thesis recommends (sec. 3.3.2)
        pixels = torch.tensor([[ac + sign * 50.0, cy - 50.0], [ac + sign * 100.0, cy + 50.0]], dtype=torch.float64)
    if focal_pixel is None:
        focal_pixel = torch.tensor([ac + sign * rig.image_width / 4.0, cy], dtype=torch.float64)
    check_shape(pixels, [2, 2], "pixels")
    check_shape(focal_pixel, [2], "focal_pixel")
    pixels, focal_pixel = pixels.to(torch.float64), focal_pixel.to(torch.float64)
    chosen = torch.cat([pixels, focal_pixel[None]])
    rays = trace_pixels(rig, chosen)
    in_half = rays.left if half == "left" else ~rays.left
    if not bool((rays.valid & in_half).all()):
        raise RigError(f"two-point pixels {chosen.tolist()} must all see through the {half} face")
    # Step 1 (eq. 3.1-3.10 + Appendix C): centre = midpoint of the back-extended rays of P_a and P_b.
    centre = ray_midpoint(rays.origins[0], rays.directions[0], rays.origins[1], rays.directions[1])
    # Step 2 (eq. 3.11-3.12): orientation from the apex (central) ray.
    axis = apex_ray(rig, half).directions
    rotation = _axes_from_direction(axis)
    # Step 3 (eq. 3.13-3.17): f_vc = |P_o P_c| / tan(phi_vc), |P_o P_c| measured on the real sensor.
    p_o = torch.tensor([ac, cy], dtype=torch.float64)
    dist_mm = (focal_pixel - p_o).norm() * rig.pixel_size_mm
    cos_phi = (axis @ rays.directions[2]).clamp(-1.0, 1.0)
    f_vc = dist_mm / torch.tan(torch.acos(cos_phi))
    fpx = f_vc / rig.pixel_size_mm
    return fpx, fpx, torch.tensor(ac, dtype=torch.float64), torch.tensor(cy, dtype=torch.float64), rotation, centre


def _least_squares(
    rig: BiPrismRig, half: Half, grid_step: int, depth_range_mm, depths: int, iterations: int, fit_pp: bool
):
    uv, rays, pts = _samples(rig, half, grid_step, depth_range_mm, depths)
    centre = closest_point_to_rays(rays.origins, rays.directions)
    r0 = _axes_from_direction(apex_ray(rig, half).directions)
    fpx = rig.focal_length_px
    # unknowns: rotation vector (3) relative to the apex-ray frame, fx, fy [, cx, cy]
    x = torch.tensor([1e-9, 0.0, 0.0, fpx, fpx, rig.apex_column, rig.cy][: 7 if fit_pp else 5], dtype=torch.float64)
    fixed_pp = torch.tensor([rig.apex_column, rig.cy], dtype=torch.float64)
    target = uv.expand(pts.shape[0], -1, -1).reshape(-1, 2)
    rel = (pts - centre).reshape(-1, 3)

    def residual(params: torch.Tensor) -> torch.Tensor:
        q = rel @ (r0 @ _rodrigues(params[:3]))  # R^T (X - C), row-wise
        pp = params[5:7] if fit_pp else fixed_pp
        u = params[3] * q[:, 0] / q[:, 2] + pp[0]
        v = params[4] * q[:, 1] / q[:, 2] + pp[1]
        return (torch.stack([u, v], dim=-1) - target).reshape(-1)

    lam = 1e-3  # Levenberg-Marquardt on the pixel reprojection error of exact correspondences
    cost = residual(x).square().sum()
    for _ in range(iterations):
        jac = torch.func.jacfwd(residual)(x)  # one forward pass per unknown
        jtj = jac.T @ jac
        step = torch.linalg.solve(jtj + lam * torch.diag(torch.diagonal(jtj)), -jac.T @ residual(x))
        new_cost = residual(x + step).square().sum()
        if new_cost < cost:
            x, cost, lam = x + step, new_cost, lam * 0.3
        else:
            lam *= 10.0
    pp = x[5:7] if fit_pp else fixed_pp
    return x[3], x[4], pp[0], pp[1], r0 @ _rodrigues(x[:3]), centre


def virtual_camera(
    rig: BiPrismRig,
    half: Half,
    method: Method = "least_squares",
    *,
    pixels: torch.Tensor | None = None,
    focal_pixel: torch.Tensor | None = None,
    depth_range_mm: tuple[float, float] = (250.0, 1500.0),
    grid_step: int = 16,
    depths: int = 8,
    iterations: int = 20,
    fit_principal_point: bool = False,
) -> VirtualCamera:
    """Build one half's virtual pinhole camera and measure how far the exact optics are from it.

    Methods:
        * ``'two_point'`` (thesis sec. 3.2): centre = midpoint of the back-extended rays of two pixels
          (``pixels``, default two pixels 50 and 100 px from the apex column near the image centre),
          orientation from the apex ray (eq. 3.11-3.12), f_vc from ``focal_pixel`` (eq. 3.13-3.17; default
          a quarter image width from the apex column on the centre row); principal point = apex pixel.
        * ``'least_squares'`` (all pixels): centre minimising the distance to the back-extended rays of a
          grid of the half's pixels; rotation, fx and fy (and cx, cy if ``fit_principal_point``) fitted by
          Levenberg-Marquardt to the pixel reprojection error of exact correspondences over
          ``depth_range_mm``. By default the principal point stays at the apex pixel: freeing it barely
          changes the error (setup 1: 0.37/1.89 px mean/max vs 0.41/1.79 px) because a principal-point
          shift and a rotation are nearly interchangeable, and it would leave ``beta`` meaningless.

    Both report non-centrality and reprojection error on the same samples (grid ``grid_step``, ``depths``
    depths uniform in inverse depth over ``depth_range_mm``). Computed in float64 (calibration, not a graph
    layer).

    Args:
        rig: the rig.
        half: 'left' (reference) or 'right'.
        method: 'two_point' or 'least_squares'.
        pixels: (2, 2) the two pixels of the two-point method.
        focal_pixel: (2,) the pixel P_c of eq. 3.13-3.17.
        depth_range_mm: (z_min, z_max) of the evaluation and fit.
        grid_step: pixel grid spacing of the samples.
        depths: number of depth samples.
        iterations: Levenberg-Marquardt iterations (least squares).
        fit_principal_point: also fit cx, cy (least squares).

    Returns:
        VirtualCamera.

    Raises:
        OptionError: unknown ``half`` or ``method``.
        RigError: bad pixels or depth range.

    Example:
        >>> vc = virtual_camera(thesis_setup1(), "left", "two_point")
        >>> round(float(vc.beta), 4), round(float(vc.centre[0]), 2)
        (0.0538, -9.17)
    """
    check_option(half, ("left", "right"), "half")
    check_option(method, _METHODS, "method")
    if method == "two_point":
        fx, fy, cx, cy, rotation, centre = _two_point(rig, half, pixels, focal_pixel)
    elif method == "least_squares":
        fx, fy, cx, cy, rotation, centre = _least_squares(
            rig, half, grid_step, depth_range_mm, depths, iterations, fit_principal_point
        )
    else:  # pragma: no cover - check_option above
        raise OptionError(method)
    return _measured(rig, half, method, (fx, fy, cx, cy), rotation, centre, depth_range_mm, grid_step, depths)


def _measured(rig: BiPrismRig, half: Half, method: Method, intrinsics: tuple[torch.Tensor, ...],
              rotation: torch.Tensor, centre: torch.Tensor, depth_range_mm: tuple[float, float], grid_step: int,
              depths: int) -> VirtualCamera:
    """The camera of ``intrinsics`` (fx, fy, cx, cy), ``rotation`` (3, 3) and ``centre`` (3,) with its
    non-centrality and reprojection error against the exact optics on the samples of :func:`virtual_camera`."""
    fx, fy, cx, cy = intrinsics
    camera = _camera(fx, fy, cx, cy, rotation, centre, rig)
    _, rays = _half_grid(rig, half, grid_step)
    dist = _line_distances(rays, centre)
    mean_err, max_err = pinhole_reprojection_error(rig, camera, half, depth_range_mm, grid_step, depths)
    return VirtualCamera(
        camera=camera,
        centre=centre,
        rotation=rotation,
        focal_length_mm=0.5 * (fx + fy) * rig.pixel_size_mm,
        beta=torch.atan2(rotation[0, 2], rotation[2, 2]),
        noncentrality_max_mm=dist.max(),
        noncentrality_rms_mm=dist.square().mean().sqrt(),
        reprojection_error_mean_px=mean_err,
        reprojection_error_max_px=max_err,
        half=half,
        method=method,
    )


def virtual_cameras(rig: BiPrismRig, method: Method = "least_squares", **kwargs) -> VirtualCameraPair:
    """Both virtual cameras of a rig (see :func:`virtual_camera` for the options).

    Example:
        >>> pair = virtual_cameras(thesis_setup1())
        >>> bool(torch.allclose(pair.left.centre[0], -pair.right.centre[0]))
        True
    """
    return VirtualCameraPair(
        virtual_camera(rig, "left", method, **kwargs), virtual_camera(rig, "right", method, **kwargs)
    )
