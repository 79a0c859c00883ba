"""A wrong board named from the images themselves: a chessboard of another size than ``--board`` (early, after the
first views of a camera) and a ChArUco board of another dictionary or size (after the run); each re-reads a few of
the images and raises one line saying what to check."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ccs_kornia.io.images import load_image_gray
from ccs_kornia.modules.detection.checks.board_size import (
    board_grid_in,
    other_board_size,
)
from ccs_kornia.modules.detection.markers.charuco import (
    CharucoDetector,
    charuco_markers,
    dictionary_hint,
    squares_hint,
)
from ccs_kornia.runtime.errors import NoResult, UserError

__all__ = ["WrongBoardWatch", "charuco_dictionary_check"]


def charuco_dictionary_check(pipeline, files: Sequence[str], found: Any, present: Any,
                             reasons: Sequence[str] = (), load: Any = None) -> None:
    """A ChArUco board found in no image because no marker of its dictionary was: which predefined dictionary finds
    markers in the images instead; or found in no more views than were refused for markers off its lattice (a wrong
    board size: a partial view of another board can fit by chance): the board size the markers fit. Either as a
    :class:`UserError` (exit status :data:`EXIT_USAGE`). ``load(k)``: view ``k`` as a grey ``uint8`` array (default:
    the file ``files[k]``)."""
    detector = pipeline.detector
    if not isinstance(detector, CharucoDetector) or not bool(present.any()):
        return
    off = sum(1 for r in reasons if r and r.endswith("wrong board size?"))
    if int(found.sum()) > off:
        return
    read = load if load is not None else (lambda k: _grey8(files[k]))
    images = [read(k) for k, ok in enumerate(present.tolist()) if ok][:8]
    board = detector.board
    images = [img for img in images if img is not None]
    if any(len(charuco_markers(img, board).ids) for img in images):
        hint = squares_hint(images, board)  # markers of the board decoded, but not where its squares put them
        if hint:
            raise UserError(hint)
        return  # the views had too few corners, not a wrong dictionary or board size
    raise UserError(dictionary_hint(images, board))


def _grey8(path: str) -> np.ndarray | None:
    """The file ``path`` as a grey ``uint8`` array (``None`` where it cannot be read), decoded as every view is."""
    image, _ = load_image_gray(path)
    return None if image is None else np.rint(image * 255).astype(np.uint8)


class WrongBoardWatch:
    """Stops a run whose first views of a camera all miss the board given but show a board of another size: a wrong
    ``--board`` is then named after those views instead of after every view and every second look (23-30 s on 11
    images). Called with each detection batch's ``(camera, view)`` keys and found flags (``on_batch`` of
    :meth:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline.run`).

    Args:
        cameras: per camera its image files (the run's views).
        board: the board size given.
        names: camera names for the message (``None``: one camera, not named).
        first: views of a camera that must all miss the board before its images are searched for another size.
        error: what is raised: the command's error for a board found in no image (:class:`NoResult`, exit status 3,
            as the whole run would end; ``calibrate-rig``: :class:`UserError`).
    """

    def __init__(self, cameras: list[list[str]], board: tuple[int, int], names: list[str] | None = None,
                 first: int = 6, error: type[UserError] = NoResult) -> None:
        self.cameras, self.board, self.names, self.first, self.error = cameras, board, names, first, error
        self.seen: list[dict[int, bool]] = [{} for _ in cameras]
        self.checked = [False] * len(cameras)

    def __call__(self, keys: list[tuple[int, int]], found) -> None:
        for (c, v), hit in zip(keys, found.tolist()):
            self.seen[c][v] = bool(hit)
        for c, seen in enumerate(self.seen):
            if self.checked[c] or len(seen) < min(self.first, len(self.cameras[c])):
                continue
            self.checked[c] = True
            if not any(seen.values()):
                self._search(c, sorted(seen)[:self.first])

    def _search(self, c: int, views: list[int]) -> None:
        grids = []
        for v in views:
            image, _ = load_image_gray(self.cameras[c][v])
            grids.append(None if image is None else board_grid_in(image))
        sizes = [None if g is None else g[0] for g in grids]
        other = other_board_size(sizes, self.board, cut=[g is not None and g[1] for g in grids])
        if other is None:
            return
        shown = sum(1 for s in sizes if s == other)
        if self.board[0] < self.board[1]:  # said the way round the board was given
            other = (other[1], other[0])
        camera = f"camera {self.names[c]}: " if self.names else ""
        raise self.error(f"{camera}board {self.board[0]}x{self.board[1]} not found in the first {len(views)} images, "
                        f"but a {other[0]}x{other[1]} board is in {shown} of them: check --board (COLSxROWS counts "
                        "inner corners, where four squares meet); stopped before the other images")
