"""Calibration boards: a plain chessboard and a ChArUco board (chessboard with ArUco markers in its white squares).

Both describe the same thing to the rest of the package: an inner-corner grid ``(cols, rows)`` in grid order
(``n = row * cols + col``) and each corner's object point. A ChArUco board's corner ids are OpenCV's
(``id = row * (squares_x - 1) + col``) and its object points are exactly
``cv2.aruco.CharucoBoard.getChessboardCorners()``: ``((col + 1) * square, (row + 1) * square, 0)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

__all__ = ["ARUCO_DICTIONARIES", "Chessboard", "CharucoBoard", "aruco_dictionary"]

#: the predefined ArUco dictionaries, by OpenCV name (tried in this order when the named one finds nothing)
ARUCO_DICTIONARIES: tuple[str, ...] = (
    "DICT_4X4_50", "DICT_4X4_100", "DICT_4X4_250", "DICT_4X4_1000",
    "DICT_5X5_50", "DICT_5X5_100", "DICT_5X5_250", "DICT_5X5_1000",
    "DICT_6X6_50", "DICT_6X6_100", "DICT_6X6_250", "DICT_6X6_1000",
    "DICT_7X7_50", "DICT_7X7_100", "DICT_7X7_250", "DICT_7X7_1000",
    "DICT_ARUCO_ORIGINAL", "DICT_APRILTAG_16h5", "DICT_APRILTAG_25h9", "DICT_APRILTAG_36h10", "DICT_APRILTAG_36h11",
)


def aruco_dictionary(name: str):
    """OpenCV's predefined dictionary ``name`` (e.g. ``"DICT_6X6_250"``).

    Raises:
        ValueError: unknown name.

    Example:
        >>> aruco_dictionary("DICT_4X4_50").bytesList.shape[0]
        50
    """
    import cv2

    key = getattr(cv2.aruco, str(name), None)
    if not str(name).startswith("DICT_") or not isinstance(key, int):
        raise ValueError(f"unknown ArUco dictionary {name!r}; expected one of {', '.join(ARUCO_DICTIONARIES)}")
    return cv2.aruco.getPredefinedDictionary(key)


@dataclass(frozen=True)
class Chessboard:
    """A plain chessboard of ``cols x rows`` inner corners, squares of side ``square``.

    Example:
        >>> b = Chessboard(4, 3, 0.5)
        >>> b.board_size, b.object_points().shape
        ((4, 3), torch.Size([12, 3]))
    """

    cols: int
    rows: int
    square: float = 1.0

    @property
    def board_size(self) -> tuple[int, int]:
        """``(cols, rows)`` inner corners."""
        return int(self.cols), int(self.rows)

    def object_points(self, dtype: torch.dtype = torch.float64) -> torch.Tensor:
        """:math:`(N, 3)` corners ``(col * square, row * square, 0)`` in grid order."""
        from ccs_kornia.camera import board_object_points

        return board_object_points(self.cols, self.rows, float(self.square), dtype=dtype)


@dataclass(frozen=True)
class CharucoBoard:
    """A ChArUco board as OpenCV's ``cv2.aruco.CharucoBoard((squares_x, squares_y), square, marker, dictionary)``.

    Args:
        squares_x, squares_y: squares along x and y (the inner grid is ``(squares_x - 1) x (squares_y - 1)``).
        square: square side (world units); marker: marker side (same units, smaller than ``square``).
        dictionary: OpenCV's dictionary name, e.g. ``"DICT_6X6_250"``.
        legacy: OpenCV's legacy layout (before 4.6: the pattern of boards with an even ``squares_y`` starts with a
            white square) ``True``/``False``; ``None``: the detector tries both on each image and keeps the one whose
            markers form a consistent lattice.

    Example:
        >>> b = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250")
        >>> b.board_size, b.num_corners, b.object_points()[0].tolist()
        ((4, 6), 24, [0.04, 0.04, 0.0])
    """

    squares_x: int
    squares_y: int
    square: float
    marker: float
    dictionary: str = "DICT_6X6_250"
    legacy: bool | None = None

    def __post_init__(self) -> None:
        if min(int(self.squares_x), int(self.squares_y)) < 3:
            raise ValueError(f"a ChArUco board needs at least 3x3 squares, got {self.squares_x}x{self.squares_y}")
        if not 0 < float(self.marker) < float(self.square):
            raise ValueError(f"marker side must be positive and smaller than the square, got {self.marker} and "
                             f"{self.square}")
        aruco_dictionary(self.dictionary)

    @property
    def board_size(self) -> tuple[int, int]:
        """``(cols, rows)`` inner corners: ``(squares_x - 1, squares_y - 1)``."""
        return int(self.squares_x) - 1, int(self.squares_y) - 1

    @property
    def num_corners(self) -> int:
        return self.board_size[0] * self.board_size[1]

    def object_points(self, dtype: torch.dtype = torch.float64) -> torch.Tensor:
        """:math:`(N, 3)` corner ``id``'s object point ``((col + 1) * square, (row + 1) * square, 0)``,
        ``id = row * cols + col`` (``cv2.aruco.CharucoBoard.getChessboardCorners()``)."""
        cols, rows = self.board_size
        j, i = torch.meshgrid(torch.arange(rows, dtype=dtype), torch.arange(cols, dtype=dtype), indexing="ij")
        s = float(self.square)
        return torch.stack([(i.flatten() + 1) * s, (j.flatten() + 1) * s, torch.zeros(cols * rows, dtype=dtype)], -1)

    def cv2_board(self, legacy: bool | None = None):
        """OpenCV's board object (``legacy``: this board's layout unless given; ``None`` counts as the new one)."""
        import cv2

        board = cv2.aruco.CharucoBoard((int(self.squares_x), int(self.squares_y)), float(self.square),
                                       float(self.marker), aruco_dictionary(self.dictionary))
        use = self.legacy if legacy is None else legacy
        board.setLegacyPattern(bool(use))
        return board

    def layouts(self) -> tuple[bool, ...]:
        """The legacy flags to try: the given one, or both (new layout first)."""
        return (False, True) if self.legacy is None else (bool(self.legacy),)

    def render(self, pixels_per_square: int = 40, margin: int = 0, legacy: bool | None = None):
        """The board as a ``uint8`` image (``cv2.aruco.CharucoBoard.generateImage``)."""
        size = (int(self.squares_x) * pixels_per_square + 2 * margin,
                int(self.squares_y) * pixels_per_square + 2 * margin)
        return self.cv2_board(legacy).generateImage(size, marginSize=margin, borderBits=1)
