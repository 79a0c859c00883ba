"""The board a command is given (``--board``, ``--charuco``, ``--aprilgrid``, ``--circles``): checked and described
once, and recorded in the JSON files as the user gave it."""

from __future__ import annotations

import argparse
from typing import Any

from ccs_kornia.modules.detection.boards import AprilGrid, CharucoBoard, CircleGrid
from ccs_kornia.runtime.errors import UserError

__all__ = ["aprilgrid_record", "board_records", "charuco_record", "circles_record", "require_circle_origin",
           "resolve_board"]

#: the options that describe a circle grid
_CIRCLE_OPTIONS = ("spacing", "asymmetric", "marked_origin", "diameter")


def _circles(args: argparse.Namespace) -> None:
    """``--circles`` with its options: ``args.circle_board``, the grid's size and ``args.square`` (its spacing: the
    world unit)."""
    if args.marker is not None or args.legacy is not None:
        raise UserError(f"--{'marker' if args.marker is not None else 'legacy'} describes a ChArUco board, not "
                        "--circles")
    if args.spacing is None:
        raise UserError("--circles needs --spacing: the distance between neighbouring dots' centres (e.g. --spacing "
                        "0.02)")
    try:
        grid = CircleGrid(args.circles[0], args.circles[1], args.spacing, args.diameter, bool(args.asymmetric),
                          bool(args.marked_origin))
    except ValueError as err:
        raise UserError(f"--circles: {err}") from None
    args.circle_board, args.board, args.detector = grid, grid.board_size, "circles"
    args.square = grid.spacing


def require_circle_origin(args: argparse.Namespace, what: str) -> None:
    """Refuse a circle grid whose dots' numbering a half turn changes (a symmetric grid without ROS-Industrial's
    marked origin, an asymmetric grid of an even number of rows) for a command that joins the board's pose across
    views or cameras (``what``: a hand-eye calibration, a rig): its dot ids cannot be told from view to view, where
    a single camera's calibration does not mind."""
    grid = getattr(args, "circle_board", None)
    if grid is None or grid.orientation_known:
        return
    cols, rows = grid.board_size
    kind = f"an asymmetric grid of {rows} rows (an even number)" if grid.asymmetric else "a symmetric grid"
    raise UserError(f"--circles {cols}x{rows}: {kind} looks the same turned by half a turn, so its dots cannot be "
                    f"numbered alike in every view of {what}: use a grid with ROS-Industrial's origin dot "
                    "(--marked-origin) or an --asymmetric grid of an odd number of rows")


def resolve_board(args: argparse.Namespace) -> None:
    """The board of a command with ``--board`` or ``--charuco``: ``args.board`` becomes the inner-corner grid either
    way, ``args.charuco_board`` the :class:`~ccs_kornia.modules.detection.boards.CharucoBoard` (or ``None``) and
    ``args.detector`` ``"charuco"`` for a ChArUco board."""
    if not hasattr(args, "charuco"):
        return
    args.charuco_board = None
    args.aprilgrid_board = None
    args.circle_board = None
    if getattr(args, "circles", None) is not None:
        _circles(args)
        return
    given = [f"--{o.replace('_', '-')}" for o in _CIRCLE_OPTIONS if getattr(args, o, None) not in (None, False)]
    if given:
        raise UserError(f"{given[0]} describes a circle grid: give --circles COLSxROWS too")
    if getattr(args, "aprilgrid", None) is not None:
        if args.marker is not None or args.legacy is not None:
            raise UserError(f"--{'marker' if args.marker is not None else 'legacy'} describes a ChArUco board, not "
                            "an --aprilgrid")

        try:
            grid = AprilGrid.from_yaml(args.aprilgrid)
        except OSError as err:
            raise UserError(f"--aprilgrid: cannot read {args.aprilgrid}: {err.strerror or err}") from None
        except ValueError as err:
            raise UserError(f"--aprilgrid: {err}") from None
        except Exception as err:  # a malformed YAML file
            raise UserError(f"--aprilgrid: {args.aprilgrid} is not a readable YAML file "
                            f"({str(err).splitlines()[0]})") from None
        args.aprilgrid_board, args.board, args.detector = grid, grid.board_size, "aprilgrid"
        args.square = grid.tag_size  # the world unit is tagSize's
        return
    if args.charuco is None:
        if args.marker is not None or args.legacy is not None:
            raise UserError(f"--{'marker' if args.marker is not None else 'legacy'} describes a ChArUco board: give "
                            "--charuco SXxSY too")
        return
    if args.marker is None:
        raise UserError("--charuco needs --marker: the marker side, in the unit of --square (e.g. --square 0.04 "
                        "--marker 0.02)")

    try:
        board = CharucoBoard(args.charuco[0], args.charuco[1], args.square, args.marker, args.dictionary, args.legacy)
    except ValueError as err:
        raise UserError(f"--charuco: {err}") from None
    args.charuco_board, args.board, args.detector = board, board.board_size, "charuco"


def charuco_record(args: argparse.Namespace) -> dict[str, Any] | None:
    """The ChArUco board of the command (``None`` for a chessboard) as the JSON files give it: OpenCV's squares,
    sides, dictionary and layout (``legacy`` null: found on each image)."""
    board = getattr(args, "charuco_board", None)
    if board is None:
        return None
    return {"squares": [board.squares_x, board.squares_y], "square": board.square, "marker": board.marker,
            "dictionary": board.dictionary, "legacy": board.legacy,
            "corner_ids": "id = row * (squares_x - 1) + col, object point ((col + 1) * square, (row + 1) * square, 0)"}


def aprilgrid_record(args: argparse.Namespace) -> dict[str, Any] | None:
    """The AprilGrid of the command (``None`` for other boards) as the JSON files give it: Kalibr's target keys and
    its corner numbering."""
    grid = getattr(args, "aprilgrid_board", None)
    if grid is None:
        return None
    return {"target_type": "aprilgrid", "tagCols": grid.tag_cols, "tagRows": grid.tag_rows, "tagSize": grid.tag_size,
            "tagSpacing": grid.tag_spacing, "dictionary": grid.dictionary,
            "corner_ids": "Kalibr's: tag t has corners base, base + 1, base + cols + 1, base + cols (bottom left, "
                          "bottom right, top right, top left; y up), cols = 2 * tagCols, "
                          "base = (t // tagCols) * 2 * cols + (t % tagCols) * 2"}


def circles_record(args: argparse.Namespace) -> dict[str, Any] | None:
    """The circle grid of the command (``None`` for other boards) as the JSON files give it: its dots, spacing,
    layout and dot numbering."""
    grid = getattr(args, "circle_board", None)
    if grid is None:
        return None
    layout = "asymmetric" if grid.asymmetric else "marked_origin" if grid.marked_origin else "symmetric"
    numbering = {"symmetric": "n = row * cols + col at (col * spacing, row * spacing, 0), OpenCV's order from the end "
                              "nearer the image's top left",
                 "asymmetric": "n = row * cols + col at ((2 * col + row % 2) * spacing, row * spacing, 0), OpenCV's",
                 "marked_origin": "n = row * cols + col at (col * spacing, row * spacing, 0), dot 0 the larger one, x "
                                  "along its row, y up its column (the print seen from the front)"}[layout]
    return {"dots": [grid.cols, grid.rows], "spacing": grid.spacing, "diameter": grid.dot_diameter, "layout": layout,
            "corner_ids": numbering}


def board_records(args: argparse.Namespace) -> dict[str, dict[str, Any]]:
    """The marker board's or circle grid's record of the command by its JSON key (empty for a chessboard)."""
    out = {}
    for key, record in (("charuco", charuco_record(args)), ("aprilgrid", aprilgrid_record(args)),
                        ("circles", circles_record(args))):
        if record:
            out[key] = record
    return out
