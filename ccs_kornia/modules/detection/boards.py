"""Calibration boards: a plain chessboard, a ChArUco board (chessboard with ArUco markers in its white squares),
Kalibr's AprilGrid (AprilTags with small black squares between their corners) and circle grids (OpenCV's symmetric
and asymmetric grids of dots, ROS-Industrial's modified grid whose larger dot marks the origin).

All describe the same thing to the rest of the package: a corner grid ``(cols, rows)`` in grid order
(``n = row * cols + col``) and each corner's object point. A ChArUco board's corner ids are OpenCV's
(``id = row * (squares_x - 1) + col``) and its object points are exactly
``cv2.aruco.CharucoBoard.getChessboardCorners()``: ``((col + 1) * square, (row + 1) * square, 0)``. An AprilGrid's
are Kalibr's (``GridCalibrationTargetAprilgrid``): ``2 * tagCols x 2 * tagRows`` tag corners, not evenly spaced
(:meth:`AprilGrid.object_points`); the pipeline takes them from :func:`grid_object_points`.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ccs_kornia.runtime.checks import check_board_size

__all__ = ["APRILGRID_BORDER_BITS", "ARUCO_DICTIONARIES", "AprilGrid", "Chessboard", "CharucoBoard", "CircleGrid",
           "aruco_dictionary", "grid_object_points"]

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
        from ccs_kornia.geometry.board_points import board_object_points

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

    def texture(self, pixels_per_square: int = 120, legacy: bool | None = None):
        """``(image, A)``: the board printed with a one-square margin (:meth:`render`) and the :math:`(2, 3)` affine
        map from object points ``(x, y)`` to its pixel coordinates (pixel centres at integers)."""
        import numpy as np

        scale = pixels_per_square / float(self.square)
        m = float(pixels_per_square)
        a = np.array([[scale, 0.0, m - 0.5], [0.0, scale, m - 0.5]])
        return self.render(pixels_per_square, margin=pixels_per_square, legacy=legacy), a


#: black border of an AprilGrid's tags, in bits (Kalibr prints its 36h11 tags with two: 10 x 10 bits a tag)
APRILGRID_BORDER_BITS = 2


@dataclass(frozen=True)
class AprilGrid:
    """Kalibr's AprilGrid target (``target_type: aprilgrid``): ``tag_cols x tag_rows`` AprilTags 36h11 of side
    ``tag_size`` (edge to edge of the black border), ``tag_spacing * tag_size`` apart, a small black square of that
    side beside each tag corner (each tag corner is then an X-junction).

    Corners are numbered as Kalibr numbers them: tag ``t`` (``t = tag_row * tag_cols + tag_col``, tag 0 at the
    board's bottom left, y up) has the corners ``base, base + 1, base + cols + 1, base + cols`` (bottom left, bottom
    right, top right, top left) with ``cols = 2 * tag_cols`` and
    ``base = (t // tag_cols) * 2 * cols + (t % tag_cols) * 2``; corner ``(r, c)`` (``id = r * cols + c``) lies at
    ``((c // 2) * (1 + spacing) * size + (c % 2) * size, (r // 2) * (1 + spacing) * size + (r % 2) * size, 0)``.

    Example:
        >>> g = AprilGrid(6, 6, 0.088, 0.3)
        >>> g.board_size, g.num_corners, g.tag_corner_ids(7)
        ((12, 12), 144, (26, 27, 39, 38))
        >>> [round(v, 4) for v in g.object_points()[27].tolist()]
        [0.2024, 0.1144, 0.0]
    """

    tag_cols: int
    tag_rows: int
    tag_size: float
    tag_spacing: float
    dictionary: str = "DICT_APRILTAG_36h11"

    def __post_init__(self) -> None:
        if min(int(self.tag_cols), int(self.tag_rows)) < 1 or int(self.tag_cols) * int(self.tag_rows) < 2:
            raise ValueError(f"an AprilGrid needs at least 2 tags, got {self.tag_cols}x{self.tag_rows}")
        if not float(self.tag_size) > 0:
            raise ValueError(f"tagSize must be positive, got {self.tag_size}")
        if not 0 < float(self.tag_spacing) <= 1:
            raise ValueError(f"tagSpacing must be in (0, 1] (the gap over the tag side), got {self.tag_spacing}")
        if int(self.tag_cols) * int(self.tag_rows) > aruco_dictionary(self.dictionary).bytesList.shape[0]:
            raise ValueError(f"{self.tag_cols}x{self.tag_rows} tags: more than {self.dictionary} has")

    @classmethod
    def from_yaml(cls, path: str) -> "AprilGrid":
        """The grid of a Kalibr target YAML (``target_type: aprilgrid``, ``tagCols``, ``tagRows``, ``tagSize``,
        ``tagSpacing``).

        Raises:
            ValueError: not an AprilGrid target, a missing or invalid key.
        """
        import yaml

        with open(path, encoding="utf-8") as fh:
            data = yaml.safe_load(fh)
        if not isinstance(data, dict):
            raise ValueError(f"{path}: not a Kalibr target YAML")
        kind = str(data.get("target_type", "")).strip("'\"")
        if kind != "aprilgrid":
            raise ValueError(f"{path}: target_type is {kind or 'missing'!r}, expected 'aprilgrid'")
        missing = [k for k in ("tagCols", "tagRows", "tagSize", "tagSpacing") if k not in data]
        if missing:
            raise ValueError(f"{path}: missing {', '.join(missing)}")
        try:
            cols, rows = int(data["tagCols"]), int(data["tagRows"])
            size, spacing = float(data["tagSize"]), float(data["tagSpacing"])
        except (TypeError, ValueError):
            raise ValueError(f"{path}: tagCols and tagRows must be integers, tagSize and tagSpacing numbers") from None
        return cls(cols, rows, size, spacing)

    @property
    def board_size(self) -> tuple[int, int]:
        """``(cols, rows)`` of the corner grid: ``(2 * tag_cols, 2 * tag_rows)``."""
        return 2 * int(self.tag_cols), 2 * int(self.tag_rows)

    @property
    def num_corners(self) -> int:
        return 4 * int(self.tag_cols) * int(self.tag_rows)

    @property
    def num_tags(self) -> int:
        return int(self.tag_cols) * int(self.tag_rows)

    def tag_corner_ids(self, tag: int) -> tuple[int, int, int, int]:
        """Corner ids of tag ``tag``: bottom left, bottom right, top right, top left (board frame, y up)."""
        cols = 2 * int(self.tag_cols)
        base = (int(tag) // int(self.tag_cols)) * 2 * cols + (int(tag) % int(self.tag_cols)) * 2
        return base, base + 1, base + cols + 1, base + cols

    def object_points(self, dtype: torch.dtype = torch.float64) -> torch.Tensor:
        """:math:`(N, 3)` corner ``id``'s object point, as Kalibr's ``createGridPoints``."""
        cols, rows = self.board_size
        r, c = torch.meshgrid(torch.arange(rows), torch.arange(cols), indexing="ij")
        r, c = r.flatten(), c.flatten()
        pitch = (1.0 + float(self.tag_spacing)) * float(self.tag_size)
        x = (c // 2).to(dtype) * pitch + (c % 2).to(dtype) * float(self.tag_size)
        y = (r // 2).to(dtype) * pitch + (r % 2).to(dtype) * float(self.tag_size)
        return torch.stack([x, y, torch.zeros_like(x)], -1)

    def pixels_per_bit(self, at_least: int = 8) -> int:
        """The smallest whole number of pixels per tag bit, at least ``at_least``, that draws the gaps
        (``tag_spacing`` tags) in whole pixels too (exact renders)."""
        bits = 6 + 2 * APRILGRID_BORDER_BITS
        for ppb in range(max(1, int(at_least)), int(at_least) + 200):
            gap = float(self.tag_spacing) * bits * ppb
            if abs(gap - round(gap)) < 1e-6:
                return ppb
        return int(at_least)

    def render(self, pixels_per_bit: int = 10, margin: int | None = None):
        """The target as Kalibr prints it, a ``uint8`` image (rows down; the board's y axis points up).

        ``margin`` defaults to twice the corner squares' side; :meth:`texture` gives the map from object points to
        its pixels.
        """
        import cv2
        import numpy as np

        bits = 6 + 2 * APRILGRID_BORDER_BITS
        tag_px = bits * int(pixels_per_bit)
        gap = int(round(float(self.tag_spacing) * tag_px))
        margin = 2 * gap if margin is None else int(margin)
        pitch = tag_px + gap
        w = int(self.tag_cols) * pitch - gap + 2 * margin
        h = int(self.tag_rows) * pitch - gap + 2 * margin
        art = np.full((h, w), 255, dtype=np.uint8)
        d = aruco_dictionary(self.dictionary)
        for t in range(self.num_tags):
            col, row = t % int(self.tag_cols), t // int(self.tag_cols)
            x0 = margin + col * pitch
            y0 = margin + (int(self.tag_rows) - 1 - row) * pitch  # tag row 0 at the bottom
            # Kalibr draws OpenCV's 36h11 marker turned by 180 degrees
            art[y0:y0 + tag_px, x0:x0 + tag_px] = np.rot90(
                cv2.aruco.generateImageMarker(d, t, tag_px, borderBits=APRILGRID_BORDER_BITS), 2)
            for cx, cy in ((x0 - gap, y0 - gap), (x0 + tag_px, y0 - gap), (x0 + tag_px, y0 + tag_px),
                           (x0 - gap, y0 + tag_px)):
                art[cy:cy + gap, cx:cx + gap] = 0
        return art

    def texture(self, pixels_per_bit: int = 12, legacy: bool | None = None):
        """``(image, A)``: the target as printed (:meth:`render`, exact pixels: :meth:`pixels_per_bit`) and the
        :math:`(2, 3)` affine map from object points ``(x, y)`` to its pixel coordinates (pixel centres at integers;
        y up on the board, down in the image). ``legacy`` is ignored (ChArUco boards' layout)."""
        import numpy as np

        ppb = self.pixels_per_bit(pixels_per_bit)
        art = self.render(ppb)
        scale = (6 + 2 * APRILGRID_BORDER_BITS) * ppb / float(self.tag_size)
        gap = round(float(self.tag_spacing) * (6 + 2 * APRILGRID_BORDER_BITS) * ppb)
        top = (int(self.tag_rows) - 1) * (1.0 + float(self.tag_spacing)) * float(self.tag_size) + float(self.tag_size)
        m = 2.0 * gap
        return art, np.array([[scale, 0.0, m - 0.5], [0.0, -scale, m + top * scale - 0.5]])


@dataclass(frozen=True)
class CircleGrid:
    r"""A grid of ``cols x rows`` dots, their centres ``spacing`` apart, as OpenCV's ``cv2.findCirclesGrid`` counts
    them (``patternSize = (cols, rows)``), dark dots on a light print or the inverse.

    * symmetric (OpenCV's ``CALIB_CB_SYMMETRIC_GRID``): dot ``n = r * cols + c`` at ``(c * spacing, r * spacing, 0)``;
    * ``asymmetric`` (``CALIB_CB_ASYMMETRIC_GRID``, rows shifted by half a pitch): dot ``n = r * cols + c`` at
      ``((2 * c + r % 2) * spacing, r * spacing, 0)``, as OpenCV's calibration sample builds them (the dots of one
      row are ``2 * spacing`` apart);
    * ``marked_origin`` (ROS-Industrial's modified circle grid, a symmetric grid): dot 0 is larger (twice the
      others' diameter) and sits at the origin; ``x`` runs along its row, ``y`` up its column when the print is seen
      from the front (``z`` towards the viewer), which fixes the grid's orientation.

    A symmetric grid without the marked origin, and an asymmetric grid of an even number of rows, look the same turned
    by half a turn: the detector then numbers the dots from the end nearer the image's top left, which a single
    camera's calibration does not mind (:attr:`orientation_known`).

    Args:
        cols, rows: dots per row and rows of dots.
        spacing: distance between neighbouring dots' centres (world units; asymmetric: half the distance between the
            dots of one row, OpenCV's ``squareSize``).
        diameter: the dots' diameter (world units) when printed (:meth:`texture`); the detection measures each dot
            and needs none. Default: half the distance to the nearest dot.
        asymmetric, marked_origin: the layout (see above); not both.

    Example:
        >>> g = CircleGrid(4, 3, 0.02, asymmetric=True)
        >>> g.board_size, [round(v, 3) for v in g.object_points()[5].tolist()]
        ((4, 3), [0.06, 0.02, 0.0])
    """

    cols: int
    rows: int
    spacing: float
    diameter: float | None = None
    asymmetric: bool = False
    marked_origin: bool = False

    def __post_init__(self) -> None:
        if min(int(self.cols), int(self.rows)) < 2 or int(self.cols) * int(self.rows) < 6:
            raise ValueError(f"a circle grid needs at least 2 dots a side and 6 in all, got {self.cols}x{self.rows}")
        if not float(self.spacing) > 0:
            raise ValueError(f"the dots' spacing must be positive, got {self.spacing}")
        if self.asymmetric and self.marked_origin:
            raise ValueError("ROS-Industrial's modified circle grid (a marked origin) is a symmetric grid")
        pitch = float(self.spacing) * (2.0 ** 0.5 if self.asymmetric else 1.0)
        if self.diameter is not None and not 0 < float(self.diameter) < pitch:
            raise ValueError(f"the dots' diameter must be positive and below their distance {pitch:g}, got "
                             f"{self.diameter}")

    @property
    def board_size(self) -> tuple[int, int]:
        """``(cols, rows)`` dots."""
        return int(self.cols), int(self.rows)

    @property
    def num_corners(self) -> int:
        return int(self.cols) * int(self.rows)

    @property
    def orientation_known(self) -> bool:
        """The dots' order is fixed by the print (a marked origin, or an asymmetric grid of an odd number of rows,
        which differs from its half-turn)."""
        return bool(self.marked_origin) or (bool(self.asymmetric) and int(self.rows) % 2 == 1)

    @property
    def dot_diameter(self) -> float:
        """The (small) dots' printed diameter: :attr:`diameter` or half the distance to the nearest dot."""
        pitch = float(self.spacing) * (2.0 ** 0.5 if self.asymmetric else 1.0)
        return float(self.diameter) if self.diameter is not None else 0.5 * pitch

    def dot_diameters(self) -> torch.Tensor:
        """:math:`(N,)` each dot's printed diameter (a marked origin: dot 0 twice the others)."""
        d = torch.full((self.num_corners,), self.dot_diameter, dtype=torch.float64)
        if self.marked_origin:
            d[0] = 2.0 * self.dot_diameter
        return d

    def object_points(self, dtype: torch.dtype = torch.float64) -> torch.Tensor:
        """:math:`(N, 3)` dot ``n``'s centre (the class docstring gives the layouts)."""
        r, c = torch.meshgrid(torch.arange(int(self.rows)), torch.arange(int(self.cols)), indexing="ij")
        r, c = r.flatten().to(dtype), c.flatten().to(dtype)
        s = float(self.spacing)
        x = (2 * c + r % 2) * s if self.asymmetric else c * s
        return torch.stack([x, r * s, torch.zeros_like(x)], -1)

    def texture(self, pixels_per_spacing: int = 48, legacy: bool | None = None):
        """``(image, A)``: the grid printed (dark dots on white, a margin of one pitch, anti-aliased edges) and the
        :math:`(2, 3)` affine map from object points ``(x, y)`` to its pixel coordinates (pixel centres at integers).
        A marked origin's grid is printed with ``y`` up, as seen from the front. ``legacy`` is ignored (ChArUco
        boards' layout)."""
        import cv2
        import numpy as np

        s = float(self.spacing)
        scale = pixels_per_spacing / s
        pts = self.object_points().numpy()[:, :2]
        margin = 2.0 * s
        w = int(np.ceil((pts[:, 0].max() + 2 * margin) * scale))
        h = int(np.ceil((pts[:, 1].max() + 2 * margin) * scale))
        flip = bool(self.marked_origin)
        a = np.array([[scale, 0.0, margin * scale - 0.5],
                      [0.0, -scale if flip else scale, (pts[:, 1].max() + margin if flip else margin) * scale - 0.5]])
        # dots drawn on an 8x finer canvas (cv2.circle's sub-pixel shift), then area-averaged: anti-aliased edges
        f, shift = 8, 4
        big = np.full((h * f, w * f), 255, dtype=np.uint8)
        centres = pts @ a[:, :2].T + a[:, 2]
        for (u, v), d in zip(centres, self.dot_diameters().tolist()):
            cu, cv_ = (u + 0.5) * f - 0.5, (v + 0.5) * f - 0.5
            cv2.circle(big, (int(round(cu * 2 ** shift)), int(round(cv_ * 2 ** shift))),
                       int(round(0.5 * d * scale * f * 2 ** shift)), 0, -1, cv2.LINE_AA, shift)
        return cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA), a


def grid_object_points(board, board_size: tuple[int, int], square: float, device: torch.device | str | None = None,
                       dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """The object points by corner id that a calibration fits: the board's own where its corners are not an even grid
    (an :class:`AprilGrid`, a :class:`CircleGrid`), else :func:`~ccs_kornia.geometry.board_points.board_object_points` of ``board_size`` and ``square``
    (chessboards and ChArUco boards: the answers do not depend on the grid's origin).

    Example:
        >>> grid_object_points(None, (3, 2), 0.5)[1].tolist()
        [0.5, 0.0, 0.0]
        >>> grid_object_points(AprilGrid(2, 1, 1.0, 0.5), (4, 2), 1.0)[:4, 0].tolist()
        [0.0, 1.0, 1.5, 2.5]
    """
    if isinstance(board, (AprilGrid, CircleGrid)):
        if check_board_size(board_size) != board.board_size:
            raise ValueError(f"board_size {tuple(board_size)} is not the {type(board).__name__}'s grid {board.board_size}")
        return board.object_points(dtype).to(device)
    from ccs_kornia.geometry.board_points import board_object_points

    return board_object_points(*check_board_size(board_size), float(square), device=device, dtype=dtype)
