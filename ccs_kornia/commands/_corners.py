"""``--corners corners.json``: the corners ``detect`` wrote given instead of images (``calibrate``, ``calibrate-rig``).

Each file is read (:func:`~ccs_kornia.io.corners_file.read_corners_file`) and checked against the command's board
options before any work: the board options still say the board's type and square size, and a file of another board
is refused in one line, as is a file that does not say its images' size when ``--image-size`` is not given. The views
then come from a :class:`~ccs_kornia.pipeline.corners_input.CornersSource`: nothing is detected again.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from typing import Any

from ccs_kornia.commands._printing import info
from ccs_kornia.io.corners_file import CornersFile, read_corners_file
from ccs_kornia.pipeline.corners_input import CornersSource
from ccs_kornia.runtime.errors import UserError

__all__ = ["check_board", "corner_files", "corners_source", "image_size_option", "report_note"]

#: the options that read images or recordings, which a corners file replaces
_IMAGE_OPTIONS = (("save_frames", "--save-frames"), ("timestamps", "--timestamps"), ("start", "--start"),
                  ("end", "--end"), ("max_frames", "--max-frames"), ("max_motion", "--max-motion"),
                  ("image_topics", "--image-topics"))


def _board_name(cf: CornersFile) -> str:
    if cf.charuco is not None:
        squares = cf.charuco.get("squares") or ["?", "?"]
        return f"{squares[0]}x{squares[1]} ChArUco board ({cf.charuco.get('dictionary', '?')})"
    if cf.aprilgrid is not None:
        return f"{cf.aprilgrid.get('tagCols', '?')}x{cf.aprilgrid.get('tagRows', '?')} AprilGrid"
    if cf.circles is not None:
        return f"{cf.board[0]}x{cf.board[1]} {cf.circles.get('layout', '')} circle grid"
    return f"{cf.board[0]}x{cf.board[1]} chessboard"


def _args_board_name(args: argparse.Namespace) -> str:
    charuco, grid = getattr(args, "charuco_board", None), getattr(args, "aprilgrid_board", None)
    if charuco is not None:
        return f"{charuco.squares_x}x{charuco.squares_y} ChArUco board ({charuco.dictionary}) of --charuco"
    if grid is not None:
        return f"{grid.tag_cols}x{grid.tag_rows} AprilGrid of --aprilgrid"
    circles = getattr(args, "circle_board", None)
    if circles is not None:
        layout = "asymmetric" if circles.asymmetric else "marked_origin" if circles.marked_origin else "symmetric"
        return f"{args.board[0]}x{args.board[1]} {layout} circle grid of --circles"
    return f"{args.board[0]}x{args.board[1]} chessboard of --board"


def check_board(cf: CornersFile, args: argparse.Namespace) -> None:
    """Refuse (:class:`UserError`, one line) a corners file whose board is not the command's: another size, another
    kind of board, another ChArUco dictionary or AprilGrid layout."""
    charuco, grid = getattr(args, "charuco_board", None), getattr(args, "aprilgrid_board", None)
    same = tuple(cf.board) == tuple(args.board) and (cf.charuco is None) == (charuco is None) \
        and (cf.aprilgrid is None) == (grid is None) \
        and (cf.circles is None) == (getattr(args, "circle_board", None) is None)
    if same and charuco is not None:
        same = list(cf.charuco.get("squares") or []) == [charuco.squares_x, charuco.squares_y] \
            and cf.charuco.get("dictionary") == charuco.dictionary
    if same and grid is not None:
        same = [cf.aprilgrid.get("tagCols"), cf.aprilgrid.get("tagRows")] == [grid.tag_cols, grid.tag_rows]
    if not same:
        raise UserError(f"--corners {cf.path}: its corners are of a {_board_name(cf)}, not the "
                        f"{_args_board_name(args)}")


def image_size_option(text: str | None) -> tuple[int, int] | None:
    """``--image-size WxH`` (``None`` when not given)."""
    if text is None:
        return None
    w, sep, h = text.lower().partition("x")
    if not sep or not w.strip().isdigit() or not h.strip().isdigit() or int(w) < 1 or int(h) < 1:
        raise UserError(f"--image-size {text}: expected WIDTHxHEIGHT in pixels, e.g. 1280x720")
    return int(w), int(h)


def corner_files(args: argparse.Namespace, paths: Sequence[str]) -> list[CornersFile]:
    """The corners files, each checked against the board options and for its image size (``--image-size`` where a
    file does not say it)."""
    size = image_size_option(getattr(args, "image_size", None))
    files = []
    for path in paths:
        cf = read_corners_file(path, tuple(args.board))
        check_board(cf, args)
        if cf.image_size is None and size is None:
            raise UserError(f"--corners {path}: the file does not say the images' size (written before detect "
                            "recorded it): give --image-size WxH")
        if cf.image_size is not None and size is not None and tuple(cf.image_size) != size:
            raise UserError(f"--image-size {size[0]}x{size[1]}: the corners of {path} are on "
                            f"{cf.image_size[0]}x{cf.image_size[1]} images")
        if not any(v.found for v in cf.views):
            raise UserError(f"--corners {path}: no view has a board ({len(cf.views)} views)")
        files.append(cf)
    return files


def corners_source(args: argparse.Namespace, inputs: Sequence[str], names: Sequence[str] | None = None) -> CornersSource | None:
    """The views of ``--corners`` (one file per camera), or ``None`` when the command is given images; refused when
    given both, or with an option that reads images."""
    paths = getattr(args, "corners", None)
    if not paths:
        if getattr(args, "image_size", None) is not None:
            raise UserError("--image-size says the size of the images of --corners files; give --corners, or leave it "
                            "out (images say their own size)")
        return None
    if inputs:
        raise UserError(f"give either images or --corners, not both: {inputs[0]} and --corners {paths[0]}")
    if getattr(args, "bag", None) is not None:
        raise UserError(f"give either --corners or --bag, not both: --corners {paths[0]} and --bag {args.bag}")
    for attr, option in _IMAGE_OPTIONS:
        if getattr(args, attr, None) is not None:
            raise UserError(f"{option} reads images or recordings; with --corners the views are the corners files'")
    real = [os.path.realpath(p) for p in paths]
    for k, path in enumerate(real):
        if path in real[:k]:
            raise UserError(f"--corners {paths[k]} is given twice: one corners file per camera")
    files = corner_files(args, paths)
    source = CornersSource(files, names, image_size_option(getattr(args, "image_size", None)))
    for cf, (w, h) in zip(files, source.sizes):
        found = sum(v.found for v in cf.views)
        info(f"{cf.path}: the board in {found} of {len(cf.views)} views of {w}x{h} images (corners given, not "
             "detected again)")
    return source


def report_note(views: list[dict[str, Any]]) -> None:
    """Say that ``--report`` draws no overlay where a view's image cannot be read (corners given)."""
    missing = sum(1 for v in views if not os.path.isfile(v["path"]))
    if missing:
        info(f"--report: no overlay of the {missing} of {len(views)} views whose images are not at the "
             "paths the corners file names (the corners were given, not detected)")
