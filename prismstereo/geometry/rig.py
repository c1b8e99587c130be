"""The physical setup: a pinhole camera with a bi-prism in front of it.

Frames and units (see :mod:`prismstereo.conventions`): camera frame x right, y down, z forward, origin at
the real camera's optical centre; lengths in mm; angles in radians internally, ``*_deg`` in user-facing
fields. Pixels (u, v) = (column, row) with pixel centres at integer coordinates.

The prism (thesis ch. 3, fig. 3.4; eq. 3.3 in our frame): the apex line is parallel to y at x = d
(``prism_offset_x_mm``) and z = T_o (``apex_distance_mm``); the two faces are z = T_o + |x - d| tan(alpha);
the back plane z = T_o + T (``prism_thickness_mm``) is parallel to the image plane. The prism is therefore
T thick at the apex and ends where the faces meet the back plane, |x - d| = T / tan(alpha): its back plane is
2 T / tan(alpha) wide. An optional tilt rotates the whole prism about the apex point (d, 0, T_o).

:class:`BiPrismRig` holds the numbers (frozen, JSON round trip, every field validated); its
:meth:`~BiPrismRig.parameters` gives the same numbers as tensors, the
:class:`~prismstereo.geometry.parameters.RigParameters` the differentiable optics consume (so every rig parameter
can be optimised, e.g. for self-calibration), and :func:`as_parameters` accepts either form.

Whether both half-images actually see through the prism needs the ray tracer, which builds on this module; that
geometric check is :func:`~prismstereo.geometry.optics.check_rig_images`, called by the entry points that take a
rig from users: :func:`~prismstereo.geometry.presets.load_rig` (rig files, JSON text, dicts, preset names), the
depth models and :class:`~prismstereo.nn.PrismCostVolume`. This module does not import the optics.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import torch

from prismstereo.errors import RigError
from prismstereo.geometry.parameters import RigParameters, split_column

__all__ = ["BiPrismRig", "as_parameters"]

_REQUIRED = (
    "alpha_deg",
    "refractive_index",
    "focal_length_mm",
    "prism_thickness_mm",
    "apex_distance_mm",
    "pixel_size_mm",
    "image_width",
    "image_height",
)
_OPTIONAL = ("principal_point", "prism_offset_x_mm", "prism_tilt_deg", "distortion")


@dataclasses.dataclass(frozen=True, kw_only=True)
class BiPrismRig:
    """A camera with a bi-prism in front of it (thesis Table 3.1 / Table 4.2 parameters).

    The JSON field names are a contract shared with other tools; see the module docstring for the
    geometry. Construction validates every field (cheap: no ray tracing, so :meth:`replace`, :meth:`binned`
    and :meth:`downscaled` stay cheap too). Whether both half-images actually see through the prism (rays
    neither miss it nor are totally internally reflected over a whole half) is checked by
    :func:`~prismstereo.geometry.optics.check_rig_images`, which :func:`~prismstereo.geometry.presets.load_rig`
    and the depth models call.

    Args:
        alpha_deg: prism corner angle alpha in degrees, in (0, 90).
        refractive_index: glass index n > 1.
        focal_length_mm: focal length f > 0.
        prism_thickness_mm: T > 0, apex to back plane.
        apex_distance_mm: T_o > 0, optical centre to apex.
        pixel_size_mm: square pixel pitch > 0.
        image_width: sensor columns (> 1).
        image_height: sensor rows (> 0).
        principal_point: (cx, cy) in px, default the image centre ((W - 1) / 2, (H - 1) / 2); must lie on
            the sensor.
        prism_offset_x_mm: d, x translation of the prism (thesis sec. 5.5), default 0.
        prism_tilt_deg: rotation of the prism about its apex point (d, 0, T_o), degrees about x, y, z
            (applied as R_z R_y R_x); default (0, 0, 0). Each angle must be in (-45, 45). The angle about z is
            the prism's roll: its apex line is then not parallel to the sensor columns and the split between
            the half-images is slanted (see :attr:`reference_width`).
        distortion: lens distortion ``(k1, k2, p1, p2, k3)`` of the real camera, OpenCV's order and meaning on
            its normalised coordinates (:mod:`prismstereo.geometry.distortion`); default all zeros, the
            pinhole. Must be invertible over the sensor (the lens model may not fold over).

    Raises:
        RigError: on any invalid value (the message names the field).

    Example:
        >>> rig = BiPrismRig(alpha_deg=6.4, refractive_index=1.48, focal_length_mm=25.0,
        ...                  prism_thickness_mm=5.6, apex_distance_mm=170.0, pixel_size_mm=0.00465,
        ...                  image_width=1024, image_height=768)
        >>> rig.principal_point
        (511.5, 383.5)
    """

    alpha_deg: float
    refractive_index: float
    focal_length_mm: float
    prism_thickness_mm: float
    apex_distance_mm: float
    pixel_size_mm: float
    image_width: int
    image_height: int
    principal_point: tuple[float, float] | None = None
    prism_offset_x_mm: float = 0.0
    prism_tilt_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    distortion: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for name in ("alpha_deg", "refractive_index", "focal_length_mm", "prism_thickness_mm",
                     "apex_distance_mm", "pixel_size_mm", "prism_offset_x_mm"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise RigError(f"{name} must be a finite number, got {value!r}")
            object.__setattr__(self, name, float(value))
        for name in ("image_width", "image_height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) and not (
                isinstance(value, float) and value.is_integer()
            ):
                raise RigError(f"{name} must be an integer number of pixels, got {value!r}")
            object.__setattr__(self, name, int(value))
        for name in ("focal_length_mm", "prism_thickness_mm", "apex_distance_mm", "pixel_size_mm"):
            if getattr(self, name) <= 0:
                raise RigError(f"{name} must be positive, got {getattr(self, name)}")
        if self.image_width < 2 or self.image_height < 1:
            raise RigError(f"image size must be at least 2x1 px, got {self.image_width}x{self.image_height}")
        if not 0.0 < self.alpha_deg < 90.0:
            raise RigError(f"alpha_deg must be in (0, 90) degrees, got {self.alpha_deg}")
        if self.refractive_index <= 1.0:
            raise RigError(f"refractive_index must be > 1 (glass in air), got {self.refractive_index}")
        pp = self.principal_point
        if pp is None:
            pp = ((self.image_width - 1) / 2.0, (self.image_height - 1) / 2.0)
        pp = _float_tuple(pp, 2, "principal_point")
        cx, cy = pp
        if not (-0.5 <= cx <= self.image_width - 0.5 and -0.5 <= cy <= self.image_height - 0.5):
            raise RigError(
                f"principal_point {pp} is off the sensor (valid: u in [-0.5, {self.image_width - 0.5}], "
                f"v in [-0.5, {self.image_height - 0.5}])"
            )
        object.__setattr__(self, "principal_point", pp)
        tilt = _float_tuple(self.prism_tilt_deg, 3, "prism_tilt_deg")
        if any(abs(t) >= 45.0 for t in tilt):
            raise RigError(f"prism_tilt_deg angles must be in (-45, 45) degrees, got {tilt}")
        object.__setattr__(self, "prism_tilt_deg", tilt)
        distortion = _float_tuple(self.distortion, 5, "distortion")
        object.__setattr__(self, "distortion", distortion)
        if any(distortion):
            _check_distortion(self)

    # ----------------------------------------------------------------------------- derived values
    @property
    def alpha_rad(self) -> float:
        """Prism corner angle alpha in radians."""
        return math.radians(self.alpha_deg)

    @property
    def cx(self) -> float:
        """Principal point column (px)."""
        return self.principal_point[0]  # type: ignore[index]

    @property
    def cy(self) -> float:
        """Principal point row (px)."""
        return self.principal_point[1]  # type: ignore[index]

    @property
    def focal_length_px(self) -> float:
        """Focal length in pixels, f / pixel_size."""
        return self.focal_length_mm / self.pixel_size_mm

    @property
    def prism_width_mm(self) -> float:
        """Width of the prism's back plane, 2 T / tan(alpha) (mm)."""
        return 2.0 * self.prism_thickness_mm / math.tan(self.alpha_rad)

    @property
    def apex_column(self) -> float:
        """Image column u where the apex point (d, 0, T_o) projects: cx + f d / (T_o pixel_size) (pinhole).

        Columns u < apex_column form the left (reference) half-image when the prism is neither rolled nor
        tilted about x and the lens is distortion-free.
        """
        return self.cx + self.focal_length_px * self.prism_offset_x_mm / self.apex_distance_mm

    @property
    def distorted(self) -> bool:
        """True if any distortion coefficient is non-zero."""
        return any(self.distortion)

    @property
    def reference_width(self) -> int:
        """W_ref: the columns that go to the reference half, clamped to [0, W].

        The columns left of the apex line's image. When the prism is rolled (or tilted about x) or the lens
        distorts, that image is a slanted or curved line and W_ref is its rightmost column over the sensor's
        rows (:func:`split_column`), so the reference crop holds every left-half pixel; the few right-half
        pixels it also holds are masked by the tracer's ``left`` flag wherever the library builds masks.

        Example:
            >>> thesis_setup1().reference_width
            512
            >>> thesis_setup1().replace(prism_tilt_deg=(0.0, 0.0, 0.3)).reference_width
            514
        """
        column = split_column(self.cx, self.cy, self.focal_length_px, self.prism_offset_x_mm, self.apex_distance_mm,
                              [math.radians(a) for a in self.prism_tilt_deg],
                              self.distortion if self.distorted else None, self.image_height)
        return min(self.image_width, max(0, math.ceil(column)))

    # ----------------------------------------------------------------------------- tensors
    def parameters(
        self,
        like: torch.Tensor | None = None,
        *,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
        requires_grad: bool = False,
    ) -> RigParameters:
        """Return the rig as :class:`RigParameters` (angles converted to radians).

        Args:
            like: take dtype and device from this tensor (overridden by ``dtype``/``device``).
            dtype: tensor dtype, default ``like.dtype`` or float32.
            device: tensor device, default ``like.device`` or CPU.
            requires_grad: make every floating field a leaf requiring grad.

        Example:
            >>> p = thesis_setup1().parameters(dtype=torch.float64, requires_grad=True)
            >>> p.alpha.requires_grad, p.tilt.shape
            (True, torch.Size([3]))
        """
        if dtype is None:
            dtype = like.dtype if like is not None else torch.get_default_dtype()
        if device is None:
            device = like.device if like is not None else None

        def t(value: Any) -> torch.Tensor:
            return torch.tensor(value, dtype=dtype, device=device, requires_grad=requires_grad)

        return RigParameters(
            alpha=t(self.alpha_rad),
            n=t(self.refractive_index),
            f=t(self.focal_length_mm),
            T=t(self.prism_thickness_mm),
            T_o=t(self.apex_distance_mm),
            pixel_size=t(self.pixel_size_mm),
            cx=t(self.cx),
            cy=t(self.cy),
            d=t(self.prism_offset_x_mm),
            tilt=t([math.radians(a) for a in self.prism_tilt_deg]),
            distortion=t(list(self.distortion)) if (self.distorted or requires_grad) else None,
            width=self.image_width,
            height=self.image_height,
        )

    def downscaled(self, factor: int) -> BiPrismRig:
        """The same field of view on a sensor ``factor`` times coarser (pixels ``factor`` times larger, image
        size divided and rounded down, principal point back at the new image centre): for quick previews
        and tests with the rig's geometry.

        Example:
            >>> small = thesis_setup1().downscaled(4)
            >>> small.image_width, small.image_height, small.pixel_size_mm
            (256, 192, 0.0186)
        """
        if not isinstance(factor, int) or factor < 1:
            raise RigError(f"factor must be a positive int, got {factor!r}")
        return self.replace(image_width=self.image_width // factor, image_height=self.image_height // factor,
                            pixel_size_mm=self.pixel_size_mm * factor, principal_point=None)

    def binned(self, factor: int) -> BiPrismRig:
        """The rig that sees the capture box-averaged over ``factor`` x ``factor`` pixel blocks
        (``F.avg_pool2d(image, factor)``): pixels ``factor`` times larger, image size divided and rounded down
        (the last W mod factor columns and H mod factor rows dropped, as the pooling drops them), principal
        point mapped exactly: block i covers pixels factor i .. factor i + factor - 1, so its centre is full
        pixel factor i + (factor - 1) / 2 and c_binned = (c - (factor - 1) / 2) / factor. (:meth:`downscaled`
        re-centres the principal point instead.)

        Example:
            >>> rig = thesis_setup1().replace(principal_point=(500.0, 380.0))
            >>> rig.binned(2).principal_point, rig.binned(2).image_width
            ((249.75, 189.75), 512)
        """
        coarse = self.downscaled(factor)  # the sizes and the pixel pitch (and the check of factor)
        cx, cy = self.principal_point  # type: ignore[misc]
        shift = (factor - 1) / 2
        return coarse.replace(principal_point=((cx - shift) / factor, (cy - shift) / factor))

    def unbinned(self, factor: int) -> BiPrismRig:
        """The rig of a sensor ``factor`` times finer whose :meth:`binned` (``factor``) is this rig: pixels ``factor``
        times smaller, image size multiplied, c_fine = factor c + (factor - 1) / 2. A model made for binned captures
        runs on this rig's captures as if they were the binned ones of the finer sensor.

        Example:
            >>> rig = thesis_setup1().downscaled(2)
            >>> rig.unbinned(2).binned(2) == rig, rig.unbinned(2).image_width
            (True, 1024)
        """
        if not isinstance(factor, int) or factor < 1:
            raise RigError(f"factor must be a positive int, got {factor!r}")
        cx, cy = self.principal_point  # type: ignore[misc]
        shift = (factor - 1) / 2
        return self.replace(image_width=self.image_width * factor, image_height=self.image_height * factor,
                            pixel_size_mm=self.pixel_size_mm / factor,
                            principal_point=(cx * factor + shift, cy * factor + shift))

    def replace(self, **changes: Any) -> BiPrismRig:
        """Return a copy with some fields changed, its fields validated (as the constructor does; no ray tracing).

        Example:
            >>> thesis_setup1().replace(prism_offset_x_mm=2.0).prism_offset_x_mm
            2.0
        """
        return dataclasses.replace(self, **changes)

    # ----------------------------------------------------------------------------- JSON
    def to_dict(self) -> dict[str, Any]:
        """The rig as a JSON-ready dict with the contract's field names (all fields written)."""
        out = dataclasses.asdict(self)
        out["principal_point"] = list(self.principal_point)  # type: ignore[arg-type]
        out["prism_tilt_deg"] = list(self.prism_tilt_deg)
        out["distortion"] = list(self.distortion)
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> BiPrismRig:
        """Build a rig from a dict with the JSON field names.

        Checks the fields only (as the constructor does); :func:`~prismstereo.geometry.presets.load_rig` also
        checks that both half-images see through the prism, and is what user-facing code should call.

        Raises:
            RigError: on missing or unknown fields, or invalid values.

        Example:
            >>> BiPrismRig.from_dict(thesis_setup1().to_dict()) == thesis_setup1()
            True
        """
        if not isinstance(data, dict):
            raise RigError(f"a rig must be a JSON object, got {type(data).__name__}")
        missing = [k for k in _REQUIRED if k not in data]
        if missing:
            raise RigError(f"rig is missing required field(s): {', '.join(missing)}")
        unknown = sorted(set(data) - set(_REQUIRED) - set(_OPTIONAL))
        if unknown:
            raise RigError(
                f"unknown rig field(s): {', '.join(unknown)}. Valid fields: {', '.join(_REQUIRED + _OPTIONAL)}"
            )
        kwargs = dict(data)
        if kwargs.get("principal_point") is not None:
            kwargs["principal_point"] = _float_tuple(kwargs["principal_point"], 2, "principal_point")
        if "prism_tilt_deg" in kwargs:
            kwargs["prism_tilt_deg"] = _float_tuple(kwargs["prism_tilt_deg"], 3, "prism_tilt_deg")
        if "distortion" in kwargs:
            kwargs["distortion"] = _float_tuple(kwargs["distortion"], 5, "distortion")
        return cls(**kwargs)

    def to_json(self, path: str | Path | None = None) -> str:
        """Serialise to JSON; also write it to ``path`` if given. Returns the JSON text.

        Example:
            >>> '"alpha_deg": 6.4' in thesis_setup1().to_json()
            True
        """
        text = json.dumps(self.to_dict(), indent=2) + "\n"
        if path is not None:
            Path(path).write_text(text)
        return text

    @classmethod
    def from_json(cls, source: str | Path) -> BiPrismRig:
        """Load a rig from a JSON file path (or a JSON string starting with ``{``).

        Checks the fields only (as the constructor does); :func:`~prismstereo.geometry.presets.load_rig` also
        checks that both half-images see through the prism, and is what user-facing code should call.

        Raises:
            RigError: if the file is missing, is not valid JSON, or holds a rig with invalid fields.

        Example:
            >>> BiPrismRig.from_json(thesis_setup2().to_json()).alpha_deg
            21.8
        """
        text = str(source)
        if not text.lstrip().startswith("{"):
            path = Path(source)
            if not path.is_file():
                raise RigError(f"rig file not found: {path}")
            text = path.read_text()
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise RigError(f"rig file is not valid JSON: {exc}") from exc
        return cls.from_dict(data)


def as_parameters(rig: BiPrismRig | RigParameters, like: torch.Tensor) -> RigParameters:
    """The rig as :class:`RigParameters` on ``like``'s dtype and device (autograd preserved): the one entry
    point through which every differentiable function accepts either a rig or its tensors.

    Raises:
        RigError: if ``rig`` is neither.

    Example:
        >>> as_parameters(thesis_setup1(), torch.zeros(1, dtype=torch.float64)).n.dtype
        torch.float64
    """
    if isinstance(rig, BiPrismRig):
        return rig.parameters(like)
    if isinstance(rig, RigParameters):
        return rig.to(like)
    raise RigError(f"rig must be a BiPrismRig or RigParameters, got {type(rig).__name__}")


def _check_distortion(rig: BiPrismRig) -> None:
    """Raise RigError unless the lens model is invertible over the sensor (round trip < 1e-6 px, no fold)."""
    from prismstereo.geometry.distortion import max_round_trip_px

    f = rig.focal_length_px
    u = torch.linspace(-0.5, rig.image_width - 0.5, 17, dtype=torch.float64)
    v = torch.linspace(-0.5, rig.image_height - 0.5, 17, dtype=torch.float64)
    uv = torch.stack(torch.meshgrid(u, v, indexing="xy"), dim=-1).reshape(-1, 2)
    xy = torch.stack([(uv[:, 0] - rig.cx) / f, (uv[:, 1] - rig.cy) / f], dim=-1)
    err = max_round_trip_px(torch.tensor(rig.distortion, dtype=torch.float64), xy, f)
    if not err < 1e-6:
        raise RigError(f"distortion {rig.distortion} is not invertible over the sensor (the lens model folds over or "
                       f"its inverse does not converge: round trip {err:.3g} px)")


def _float_tuple(value: Any, length: int, name: str) -> tuple[float, ...]:
    try:
        items = tuple(float(v) for v in value)
    except (TypeError, ValueError) as exc:
        raise RigError(f"{name} must be a list of {length} numbers, got {value!r}") from exc
    if len(items) != length or not all(math.isfinite(v) for v in items):
        raise RigError(f"{name} must be a list of {length} finite numbers, got {value!r}")
    return items
