"""Calibration targets: chessboards and ChArUco boards, their geometry and their pictures.

Board frame: origin at the board's reference corner, x along the columns, y along the
rows, z into the board (OpenCV's convention, so board points have z = 0) [m].

* chessboard ``COLSxROWS``: counts of **inner** corners (where four squares meet); the
  origin is the first inner corner, corner ``i`` (row-major, x fastest) sits at
  ``(i % cols, i // cols, 0) * square``, the order :func:`cv2.findChessboardCorners` reports.
* ChArUco ``SQUARESXxSQUARESY``: counts of **squares**; the origin is the board's outer
  top-left corner and the corner ids are OpenCV's (``board.getChessboardCorners()``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

from factory.core.errors import CalibrationError

#: The ``--board`` grammar, for error messages.
BOARD_SYNTAX = "chessboard:COLSxROWS:SQUARE_M or charuco:SQUARESXxSQUARESY:SQUARE_M:MARKER_M:DICT"

_SIZE = re.compile(r"^(\d+)[xX](\d+)$")


def _positive(text: str, what: str, spec: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not np.isfinite(value) or value <= 0:
        raise CalibrationError(f"{what} must be a positive length in metres, got {text!r} in {spec!r}",
                               source="--board")
    return value


@dataclass(frozen=True)
class BoardSpec:
    """A planar calibration board.

    Attributes
    ----------
    kind : str
        ``"chessboard"`` or ``"charuco"``.
    cols, rows : int
        Chessboard: inner corners across and down. ChArUco: squares across and down.
    square : float
        Edge of one square [m].
    marker : float
        ChArUco marker edge [m] (0 for a chessboard).
    dictionary : str
        ChArUco ArUco dictionary name, e.g. ``"DICT_6X6_250"`` (empty for a chessboard).
    """

    kind: str
    cols: int
    rows: int
    square: float
    marker: float = 0.0
    dictionary: str = ""

    def __post_init__(self) -> None:
        if self.kind not in ("chessboard", "charuco"):
            raise CalibrationError(f"unknown board kind {self.kind!r}; expected {BOARD_SYNTAX}", source="--board")
        least = 2 if self.kind == "chessboard" else 3
        if self.cols < least or self.rows < least:
            raise CalibrationError(f"{self.kind} needs at least {least}x{least} "
                                   f"{'inner corners' if self.kind == 'chessboard' else 'squares'}, "
                                   f"got {self.cols}x{self.rows}", source="--board")
        if not (np.isfinite(self.square) and self.square > 0):
            raise CalibrationError(f"square size must be positive, got {self.square}", source="--board")
        if self.kind == "charuco":
            if not 0 < self.marker < self.square:
                raise CalibrationError(f"marker size {self.marker} m must be between 0 and the square size "
                                       f"{self.square} m", source="--board")
            if not self.dictionary.startswith("DICT_") or not hasattr(cv2.aruco, self.dictionary):
                raise CalibrationError(f"unknown ArUco dictionary {self.dictionary!r} (e.g. DICT_6X6_250)",
                                       source="--board")

    @classmethod
    def parse(cls, text: str) -> "BoardSpec":
        """Read ``chessboard:9x6:0.025`` or ``charuco:5x7:0.04:0.02:DICT_6X6_250`` (lengths [m]).

        Raises
        ------
        CalibrationError
            (``source="--board"``) The text does not follow the grammar or its values are invalid.
        """
        parts = text.strip().split(":")
        kind = parts[0].lower()
        expected = {"chessboard": 3, "charuco": 5}.get(kind)
        if expected is None or len(parts) != expected:
            raise CalibrationError(f"cannot read board {text!r}; expected {BOARD_SYNTAX}", source="--board")
        size = _SIZE.match(parts[1])
        if size is None:
            raise CalibrationError(f"board size {parts[1]!r} is not COLSxROWS, e.g. 9x6", source="--board")
        cols, rows = int(size[1]), int(size[2])
        square = _positive(parts[2], "square size", text)
        if kind == "chessboard":
            return cls("chessboard", cols, rows, square)
        marker = _positive(parts[3], "marker size", text)
        return cls("charuco", cols, rows, square, marker, parts[4].upper())

    def __str__(self) -> str:
        if self.kind == "chessboard":
            return f"chessboard:{self.cols}x{self.rows}:{self.square:g}"
        return f"charuco:{self.cols}x{self.rows}:{self.square:g}:{self.marker:g}:{self.dictionary}"

    @property
    def corner_count(self) -> int:
        """Number of corners a full view of the board shows."""
        if self.kind == "chessboard":
            return self.cols * self.rows
        return (self.cols - 1) * (self.rows - 1)

    @cached_property
    def object_points(self) -> np.ndarray:
        """``(corner_count, 3) float`` every corner in the board frame [m], indexed by corner id."""
        if self.kind == "chessboard":
            j, i = np.mgrid[0:self.rows, 0:self.cols]
            p = np.stack([i.ravel(), j.ravel(), np.zeros(i.size)], axis=1) * self.square
        else:
            p = np.asarray(self.charuco_board().getChessboardCorners(), dtype=np.float64).reshape(-1, 3)
        p.setflags(write=False)
        return p

    def charuco_board(self) -> "cv2.aruco.CharucoBoard":
        """The OpenCV board object of a ChArUco spec (a new object: OpenCV's are mutable)."""
        if self.kind != "charuco":
            raise CalibrationError("not a ChArUco board", source=str(self))
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.cols, self.rows), self.square, self.marker, dictionary)

    def texture(self, pixels_per_square: int = 64) -> "PlanarTexture":
        """A printable picture of the board with a white quiet zone, placed in the board frame.

        Parameters
        ----------
        pixels_per_square : int
            Resolution of the picture [px per square].
        """
        n = int(pixels_per_square)
        margin = n  # a full white square around the pattern: detectors need the quiet zone
        if self.kind == "chessboard":
            sq_x, sq_y = self.cols + 1, self.rows + 1
            j, i = np.mgrid[0:sq_y * n, 0:sq_x * n] // n
            pattern = np.where((i + j) % 2 == 0, 0, 255).astype(np.uint8)
            image = np.full((sq_y * n + 2 * margin, sq_x * n + 2 * margin), 255, np.uint8)
            image[margin:margin + sq_y * n, margin:margin + sq_x * n] = pattern
            # The first inner corner is one square in from the pattern's outer corner.
            origin = (margin + n, margin + n)
        else:
            size = (self.cols * n + 2 * margin, self.rows * n + 2 * margin)
            image = self.charuco_board().generateImage(size, marginSize=margin, borderBits=1)
            origin = (margin, margin)
        return PlanarTexture(image=image, pixel_size=self.square / n, origin=origin)


@dataclass(frozen=True)
class PlanarTexture:
    """A picture lying in the z = 0 plane of its frame.

    Attributes
    ----------
    image : (h, w) or (h, w, 3) uint8
    pixel_size : float
        Edge of one picture pixel on the plane [m].
    origin : (float, float)
        Where the frame origin lies in the picture, in pixel-edge coordinates (the top-left
        corner of pixel (0, 0) is (0, 0); x right, y down) [px]. Plane point (X, Y) [m] is at
        picture coordinates ``origin + (X, Y) / pixel_size``.
    """

    image: np.ndarray
    pixel_size: float
    origin: tuple[float, float]
