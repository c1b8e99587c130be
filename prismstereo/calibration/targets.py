"""Calibration boards and their detection in both half-images of a bi-prism capture.

A board is a plane of known points (board frame: origin at the first inner corner, x along the board's
columns, y along its rows, z = 0, mm). Through the prism the camera sees it twice, once per half-image; each
half is searched on its own with OpenCV (``findChessboardCornersSB`` for checkerboards, ``CharucoDetector`` for
ChArUco boards), the corners are refined by point symmetry (:mod:`~prismstereo.calibration.corners`), and they
keep the board's ids so that both halves refer to the same board points.

Target strings follow the CLI contract: ``checkerboard:COLSxROWS:SQUARE_MM`` (COLS x ROWS *inner* corners,
OpenCV's ``patternSize``) and ``charuco:COLSxROWS:SQUARE_MM:MARKER_MM:DICT`` (COLS x ROWS *squares*, DICT an
OpenCV dictionary such as ``DICT_4X4_50``).
"""

from __future__ import annotations

import dataclasses
from typing import Literal, NamedTuple

import cv2
import numpy as np
import torch

from prismstereo.calibration.corners import corner_spacing, refine_corners
from prismstereo.errors import CalibrationError
from prismstereo.geometry.rig import BiPrismRig

__all__ = [
    "Board", "HalfDetection", "ViewDetection", "CornerMethod", "parse_target", "detect_board", "to_gray", "to_gray_u8",
]

BoardKind = Literal["checkerboard", "charuco"]
CornerMethod = Literal["symmetric", "opencv"]
CORNER_METHODS: tuple[str, ...] = ("symmetric", "opencv")


@dataclasses.dataclass(frozen=True, kw_only=True)
class Board:
    """A planar calibration target.

    Args:
        kind: 'checkerboard' or 'charuco'.
        cols: inner corners per row (checkerboard) or squares per row (ChArUco), >= 3 / >= 2.
        rows: inner corners per column (checkerboard) or squares per column (ChArUco).
        square_mm: side of a square (mm).
        marker_mm: side of a ChArUco marker (mm), < square_mm; 0 for a checkerboard.
        dictionary: OpenCV ArUco dictionary name for ChArUco (e.g. 'DICT_4X4_50').

    Raises:
        CalibrationError: on invalid values.

    Example:
        >>> Board(kind="checkerboard", cols=4, rows=7, square_mm=6.0).points().shape
        torch.Size([28, 3])
    """

    kind: BoardKind
    cols: int
    rows: int
    square_mm: float
    marker_mm: float = 0.0
    dictionary: str = ""

    def __post_init__(self) -> None:
        if self.kind not in ("checkerboard", "charuco"):
            raise CalibrationError(f"unknown target kind {self.kind!r}; valid: checkerboard, charuco")
        least = 3 if self.kind == "checkerboard" else 2
        if not (isinstance(self.cols, int) and isinstance(self.rows, int) and min(self.cols, self.rows) >= least):
            raise CalibrationError(f"a {self.kind} needs integer COLSxROWS >= {least}, got {self.cols}x{self.rows}")
        if self.kind == "checkerboard" and self.cols == self.rows:
            raise CalibrationError(f"a checkerboard needs COLS != ROWS (a square grid of corners has no orientation, "
                                   f"so the two halves' corners could not be matched), got {self.cols}x{self.rows}")
        if not self.square_mm > 0:
            raise CalibrationError(f"square_mm must be positive, got {self.square_mm}")
        if self.kind == "charuco":
            if not 0 < self.marker_mm < self.square_mm:
                raise CalibrationError(f"marker_mm must be in (0, square_mm = {self.square_mm}), got {self.marker_mm}")
            if not hasattr(cv2.aruco, self.dictionary) or not self.dictionary.startswith("DICT_"):
                valid = ", ".join(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
                raise CalibrationError(f"unknown ArUco dictionary {self.dictionary!r}; valid: {valid}")
            size = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary)).bytesList.shape[0]
            if self.cols * self.rows // 2 > size:
                raise CalibrationError(f"a {self.cols}x{self.rows} ChArUco board has {self.cols * self.rows // 2} "
                                       f"markers but {self.dictionary} only {size}: a larger dictionary or a smaller "
                                       "board")

    @property
    def num_points(self) -> int:
        """Number of board points (inner corners)."""
        if self.kind == "checkerboard":
            return self.cols * self.rows
        return (self.cols - 1) * (self.rows - 1)

    def points(self) -> torch.Tensor:
        """(N, 3) float64 board points in the board frame (mm), indexed by corner id.

        Checkerboard id k is OpenCV's k-th corner of ``patternSize`` (cols, rows): (k mod cols, k div cols)
        squares; ChArUco ids are OpenCV's ``getChessboardCorners`` order, shifted to the first inner corner.
        """
        inner = self.cols if self.kind == "checkerboard" else self.cols - 1
        k = torch.arange(self.num_points, dtype=torch.float64)
        xy = torch.stack([k % inner, torch.div(k, inner, rounding_mode="floor")], dim=-1) * self.square_mm
        return torch.cat([xy, torch.zeros_like(xy[:, :1])], dim=-1)

    def charuco_board(self) -> cv2.aruco.CharucoBoard:
        """The OpenCV board object of a ChArUco target (lengths in mm)."""
        if self.kind != "charuco":
            raise CalibrationError("charuco_board() needs a ChArUco target")
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.cols, self.rows), self.square_mm, self.marker_mm, dictionary)

    def describe(self) -> str:
        """The target string of the CLI contract (round trip of :func:`parse_target`)."""
        if self.kind == "checkerboard":
            return f"checkerboard:{self.cols}x{self.rows}:{self.square_mm:g}"
        return f"charuco:{self.cols}x{self.rows}:{self.square_mm:g}:{self.marker_mm:g}:{self.dictionary}"


def parse_target(text: str) -> Board:
    """Parse a CLI target string (module docstring).

    Raises:
        CalibrationError: with the expected forms.

    Example:
        >>> parse_target("charuco:5x7:10:7:DICT_4X4_50").num_points
        24
    """
    forms = ("checkerboard:COLSxROWS:SQUARE_MM or charuco:COLSxROWS:SQUARE_MM:MARKER_MM:DICT "
             "(e.g. checkerboard:9x6:25 or charuco:5x7:30:22:DICT_4X4_50)")
    parts = str(text).split(":")
    try:
        kind = parts[0]
        cols, rows = (int(x) for x in parts[1].lower().split("x"))
        if kind == "checkerboard" and len(parts) == 3:
            return Board(kind="checkerboard", cols=cols, rows=rows, square_mm=float(parts[2]))
        if kind == "charuco" and len(parts) == 5:
            return Board(kind="charuco", cols=cols, rows=rows, square_mm=float(parts[2]), marker_mm=float(parts[3]),
                         dictionary=parts[4])
    except CalibrationError:
        raise
    except (IndexError, ValueError) as exc:
        raise CalibrationError(f"cannot parse target {text!r}; expected {forms}") from exc
    raise CalibrationError(f"cannot parse target {text!r}; expected {forms}")


class HalfDetection(NamedTuple):
    """Board corners found in one half-image.

    Attributes:
        uv: (N, 2) float64 corner positions in full-sensor pixels.
        ids: (N,) int64 board point ids (rows of :meth:`Board.points`).
    """

    uv: torch.Tensor
    ids: torch.Tensor


class ViewDetection(NamedTuple):
    """The board in one capture: each half's corners, or None where the board was not found."""

    left: HalfDetection | None
    right: HalfDetection | None


def to_gray(image: torch.Tensor | np.ndarray) -> torch.Tensor:
    """An image as an (H, W) float64 grey tensor in [0, 1]: a (C, H, W) / (H, W) float tensor in [0, 1] (channels
    averaged, full precision kept) or an (H, W) / (H, W, 3) uint8 array as read by ``cv2.imread`` (BGR converted
    to grey).

    Example:
        >>> to_gray(torch.ones(3, 4, 5)).shape
        torch.Size([4, 5])
    """
    if isinstance(image, torch.Tensor):
        img = image.detach().to(torch.float64) / (255.0 if image.dtype == torch.uint8 else 1.0)
        if img.dim() == 3:
            img = img.mean(0)
        if img.dim() != 2:
            raise CalibrationError(f"image must be (C, H, W) or (H, W), got shape {tuple(image.shape)}")
        return img.clamp(0, 1).cpu()
    arr = np.asarray(image)
    if arr.ndim == 3:
        if arr.shape[2] not in (1, 3):
            raise CalibrationError(f"an array image must be (H, W) or (H, W, 3) (OpenCV's layout), got {arr.shape}")
        arr = arr[..., 0] if arr.shape[2] == 1 else cv2.cvtColor(arr.astype(np.float32) if arr.dtype != np.uint8
                                                                 else arr, cv2.COLOR_BGR2GRAY)
    if arr.ndim != 2:
        raise CalibrationError(f"image must be (H, W) or (H, W, 3), got shape {arr.shape}")
    if arr.dtype == np.uint8:
        return torch.from_numpy(arr.astype(np.float64) / 255.0)
    return torch.from_numpy(np.clip(arr.astype(np.float64) / (1.0 if arr.max() <= 1.0 else 255.0), 0.0, 1.0))


def to_gray_u8(image: torch.Tensor | np.ndarray) -> np.ndarray:
    """An image as an (H, W) uint8 array for OpenCV's detectors (see :func:`to_gray`).

    Example:
        >>> to_gray_u8(torch.ones(1, 4, 5)).shape
        (4, 5)
    """
    if isinstance(image, np.ndarray) and image.dtype == np.uint8 and image.ndim == 2:
        return image
    return (to_gray(image) * 255.0).round().to(torch.uint8).numpy()


def _checkerboard(gray: np.ndarray, board: Board) -> HalfDetection | None:
    flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCornersSB(gray, (board.cols, board.rows), flags=flags)
    if not found:
        return None
    uv = torch.from_numpy(corners.reshape(-1, 2).astype(np.float64))
    return HalfDetection(uv, torch.arange(board.num_points))


def _charuco(gray: np.ndarray, board: Board) -> HalfDetection | None:
    detector = cv2.aruco.CharucoDetector(board.charuco_board())
    corners, ids, _, _ = detector.detectBoard(gray)
    if ids is None or len(ids) < 4:
        return None
    return HalfDetection(torch.from_numpy(corners.reshape(-1, 2).astype(np.float64)),
                         torch.from_numpy(ids.reshape(-1).astype(np.int64)))


def _consistent(left: HalfDetection, right: HalfDetection, board: Board) -> HalfDetection:
    """Give the right half's checkerboard corners the left half's ids: a checkerboard's corner order is defined
    up to a half turn (OpenCV starts at either end), while both halves see the board unmirrored and turned by
    well under a degree against each other, so the order whose first row and diagonal point the same way as
    the left half's is the right one."""
    def score(uv: torch.Tensor) -> float:
        rows = uv[board.cols - 1] - uv[0]
        diag = uv[-1] - uv[0]
        lr, ld = left.uv[board.cols - 1] - left.uv[0], left.uv[-1] - left.uv[0]
        return float(torch.nn.functional.cosine_similarity(rows, lr, dim=0)
                     + torch.nn.functional.cosine_similarity(diag, ld, dim=0))

    flipped = right.uv.flip(0)
    return right if score(right.uv) >= score(flipped) else HalfDetection(flipped, right.ids)


def detect_board(
    image: torch.Tensor | np.ndarray, rig: BiPrismRig, board: Board, *, corners: CornerMethod = "symmetric"
) -> ViewDetection:
    """Find the board in each half-image of one capture.

    The halves are split at the rig's reference width (:attr:`BiPrismRig.reference_width`) and searched
    separately with OpenCV; positions come back in full-sensor pixels (pixel centres at integers, as OpenCV's).
    With ``corners='symmetric'`` (default) each corner is then refined to the centre of point symmetry of its
    half-image (:func:`~prismstereo.calibration.corners.refine_corners`, on the full-precision image), closer to
    the exact projections than OpenCV's own sub-pixel corners on rendered boards (``benchmarks/corners.py``);
    ChArUco corners that do not converge (e.g. cut by the half's edge) are dropped, a checkerboard's keep the
    detector's position.

    Args:
        image: one capture, (C, H, W) / (H, W) float tensor in [0, 1] or a uint8 array (see :func:`to_gray`).
        rig: the (nominal) rig: its sensor size is checked, its split used.
        board: the target.
        corners: 'symmetric' or 'opencv' (the detectors' positions as they are).

    Returns:
        ViewDetection(left, right), each a :class:`HalfDetection` (uv (N, 2) float64, ids (N,)) or None.

    Raises:
        CalibrationError: the image's size is not the rig's, or an unknown ``corners``.

    Example:
        >>> det = detect_board(torch.zeros(1, 768, 1024), thesis_setup1(), parse_target("checkerboard:4x7:6"))
        >>> det.left is None and det.right is None
        True
    """
    if corners not in CORNER_METHODS:
        raise CalibrationError(f"unknown corners {corners!r}; valid: {', '.join(CORNER_METHODS)}")
    fine = to_gray(image)
    gray = (fine * 255.0).round().to(torch.uint8).numpy()
    if gray.shape != (rig.image_height, rig.image_width):
        raise CalibrationError(f"image is {gray.shape[1]}x{gray.shape[0]} px but the rig's sensor is "
                               f"{rig.image_width}x{rig.image_height}")
    split = rig.reference_width
    find = _checkerboard if board.kind == "checkerboard" else _charuco
    halves = []
    for lo, hi in ((0, split), (split, rig.image_width)):
        found = find(np.ascontiguousarray(gray[:, lo:hi]), board)
        if found is not None and corners == "symmetric":
            found = _refined(fine[:, lo:hi], found, board)
        if found is not None:
            found = HalfDetection(found.uv + torch.tensor([float(lo), 0.0], dtype=torch.float64), found.ids)
        halves.append(found)
    left, right = halves
    if left is not None and right is not None and board.kind == "checkerboard":
        right = _consistent(left, right, board)
    return ViewDetection(left, right)


def found_instead(image: torch.Tensor | np.ndarray, rig: BiPrismRig, board: Board) -> str | None:
    """What a capture's halves show where ``board`` was not found, for an error that helps: a checkerboard of another
    size (OpenCV's detector asked for any board of at least 3 x 3 inner corners), or ChArUco markers of the board's
    dictionary without its layout; None if nothing.

    Example:
        >>> found_instead(torch.zeros(1, 768, 1024), thesis_setup1(), parse_target("checkerboard:4x7:6")) is None
        True
    """
    gray = to_gray_u8(image)
    split = rig.reference_width
    markers, sizes = 0, []
    for half in (gray[:, :split], gray[:, split:]):
        half = np.ascontiguousarray(half)
        if board.kind == "charuco":
            detector = cv2.aruco.ArucoDetector(board.charuco_board().getDictionary())
            _, ids, _ = detector.detectMarkers(half)
            markers = max(markers, 0 if ids is None else len(ids))
        flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_LARGER
        found, _, meta = cv2.findChessboardCornersSBWithMeta(half, (3, 3), flags)
        if found and meta is not None:
            sizes.append(tuple(sorted(meta.shape[:2])))
    if markers:
        return f"{board.dictionary} markers, but not a {board.cols}x{board.rows} ChArUco board"
    if sizes:  # the larger where a half shows only part of the board
        return "a checkerboard of {}x{} inner corners".format(*max(sizes, key=lambda size: size[0] * size[1]))
    return None


def _refined(gray: torch.Tensor, found: HalfDetection, board: Board) -> HalfDetection | None:
    """``found`` with its corners refined by point symmetry; None if fewer than 4 remain (a checkerboard, whose
    corners must all be present, keeps every corner, refined where the refinement converged)."""
    if found.uv.shape[0] < 2:
        return found
    # ChArUco markers' inner bits start a quarter square from each corner; a checkerboard is symmetric further out.
    fraction = 0.3 if board.kind == "checkerboard" else 0.15
    radius = (fraction * corner_spacing(found.uv)).clamp(2.0, 10.0)
    ref = refine_corners(gray, found.uv, radius_px=radius)
    if board.kind == "checkerboard":
        return HalfDetection(ref.uv, found.ids)
    keep = ref.converged
    if int(keep.sum()) < 4:
        return None
    return HalfDetection(ref.uv[keep], found.ids[keep])
