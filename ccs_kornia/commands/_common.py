"""What the commands share: the user-error type, messages, devices, output checks, streaming detection."""

from __future__ import annotations

import argparse
import functools
import os
import sys
from collections.abc import Sequence
from typing import Any

__all__ = [
    "PROG",
    "UserError",
    "NoResult",
    "EXIT_OK",
    "EXIT_INTERNAL",
    "EXIT_USAGE",
    "EXIT_NO_RESULT",
    "EXIT_INTERRUPTED",
    "warn",
    "info",
    "resolve_device",
    "check_output_file",
    "check_output_dir",
    "make_dir",
    "inputs",
    "resolve_board",
    "make_detector_from",
    "charuco_dictionary_check",
    "charuco_record",
    "aprilgrid_record",
    "pipeline_options",
    "missing_weights",
    "make_pipeline",
    "run_files",
    "board_size_hint",
    "not_found_message",
    "parse_pair",
    "WrongBoardWatch",
    "weak_lines",
]

PROG = "ccs_kornia"


from ccs_kornia.runtime.errors import (  # noqa: F401  (the command line's errors and exit statuses)
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    EXIT_NO_RESULT,
    EXIT_OK,
    EXIT_USAGE,
    NoResult,
    UserError,
)


def warn(command: str, message: str) -> None:
    print(f"{PROG} {command}: warning: {message}", file=sys.stderr)


def info(message: str) -> None:
    print(message, file=sys.stderr)


def resolve_device(text: str):
    import torch

    if text.startswith("cuda"):
        if not torch.cuda.is_available():
            raise UserError(f"--device {text} requested but CUDA is not available on this machine; use --device cpu")
        index = int(text[5:]) if ":" in text else 0
        if index >= torch.cuda.device_count():
            raise UserError(f"--device {text}: only {torch.cuda.device_count()} CUDA device(s) present")
    return torch.device(text)


def _try_write_in(option: str, path: str, directory: str) -> None:
    """Create and remove a temporary file in ``directory``: the only sure test that files can be written there
    (``os.access`` says yes for root in ``/proc`` or on a read-only mount)."""
    import tempfile

    try:
        fd, probe = tempfile.mkstemp(prefix=".ccs_write_test_", dir=directory)
    except OSError as err:
        raise UserError(f"{option} {path}: cannot write in {directory} ({err.strerror or err})") from None
    os.close(fd)
    os.unlink(probe)


def check_output_file(option: str, path: str) -> None:
    """Refuse, before any work, an output file that could not be written: a directory, a missing parent directory
    (not created, so a mistyped path fails at once), a directory where no file can be created, or an existing file
    that is not writable."""
    directory = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise UserError(f"{option} {path} is a directory; give a file name")
    if not os.path.isdir(directory):
        raise UserError(f"{option} {path}: output directory {directory} does not exist (create it first)")
    if not os.access(directory, os.W_OK):
        raise UserError(f"{option} {path}: output directory {directory} is not writable")
    if os.path.exists(path) and not os.access(path, os.W_OK):
        raise UserError(f"{option} {path}: the existing file is not writable")
    _try_write_in(option, path, directory)


def check_output_dir(option: str, path: str) -> None:
    """Refuse, before any work, an output directory that could not be made or written, without creating it (a run
    that fails leaves no empty directory behind; :func:`make_dir` creates it once there is something to write)."""
    target = os.path.abspath(path)
    if os.path.exists(target) and not os.path.isdir(target):
        raise UserError(f"{option} {path} exists and is not a directory")
    existing = target
    while not os.path.isdir(existing):  # the nearest existing ancestor is where the first directory gets created
        parent = os.path.dirname(existing)
        if os.path.exists(existing) or parent == existing:
            raise UserError(f"{option} {path}: cannot create directory ({existing} is not a directory)")
        existing = parent
    _try_write_in(option, path, existing)


def make_dir(option: str, path: str) -> None:
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as err:
        raise UserError(f"{option} {path}: cannot create directory ({err.strerror or err})") from None
    if not os.path.isdir(path):
        raise UserError(f"{option} {path} exists and is not a directory")


def inputs(command: str, items: Sequence[str]) -> list[str]:
    from ccs_kornia.io.images import expand_inputs
    files, problems = expand_inputs(items)
    if not files:
        detail = "; ".join(f"{item}: {reason}" for item, reason in problems) or "nothing given"
        raise UserError(f"no images found ({detail})")
    for item, reason in problems:
        warn(command, f"{item}: {reason}")
    return files


def resolve_board(args: argparse.Namespace) -> None:
    """The board of a command with ``--board`` or ``--charuco``: ``args.board`` becomes the inner-corner grid either
    way, ``args.charuco_board`` the :class:`~ccs_kornia.modules.detection.boards.CharucoBoard` (or ``None``) and
    ``args.detector`` ``"charuco"`` for a ChArUco board."""
    if not hasattr(args, "charuco"):
        return
    args.charuco_board = None
    args.aprilgrid_board = None
    if getattr(args, "aprilgrid", None) is not None:
        if args.marker is not None or args.legacy is not None:
            raise UserError(f"--{'marker' if args.marker is not None else 'legacy'} describes a ChArUco board, not "
                            "an --aprilgrid")
        from ccs_kornia.modules.detection.boards import AprilGrid

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
    from ccs_kornia.modules.detection.boards import CharucoBoard

    try:
        board = CharucoBoard(args.charuco[0], args.charuco[1], args.square, args.marker, args.dictionary, args.legacy)
    except ValueError as err:
        raise UserError(f"--charuco: {err}") from None
    args.charuco_board, args.board, args.detector = board, board.board_size, "charuco"


def charuco_dictionary_check(pipeline, files: Sequence[str], found: Any, present: Any,
                             reasons: Sequence[str] = (), load: Any = None) -> None:
    """A ChArUco board found in no image because no marker of its dictionary was: which predefined dictionary finds
    markers in the images instead; or found in no more views than were refused for markers off its lattice (a wrong
    board size: a partial view of another board can fit by chance): the board size the markers fit. Either as a
    :class:`UserError` (exit status :data:`EXIT_USAGE`). ``load(k)``: view ``k`` as a grey ``uint8`` array (default:
    the file ``files[k]``)."""
    from ccs_kornia.modules.detection.markers.charuco import (
        CharucoDetector,
        dictionary_hint,
    )

    detector = pipeline.detector
    if not isinstance(detector, CharucoDetector) or not bool(present.any()):
        return
    off = sum(1 for r in reasons if r and r.endswith("wrong board size?"))
    if int(found.sum()) > off:
        return
    import cv2

    read = load if load is not None else (lambda k: cv2.imread(files[k], cv2.IMREAD_GRAYSCALE))
    images = [read(k) for k, ok in enumerate(present.tolist()) if ok][:8]
    board = detector.board
    from ccs_kornia.modules.detection.markers.charuco import charuco_markers

    images = [img for img in images if img is not None]
    if any(len(charuco_markers(img, board).ids) for img in images):
        from ccs_kornia.modules.detection.markers.charuco import squares_hint

        hint = squares_hint(images, board)  # markers of the board decoded, but not where its squares put them
        if hint:
            raise UserError(hint)
        return  # the views had too few corners, not a wrong dictionary or board size
    raise UserError(dictionary_hint(images, board))


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


def make_detector_from(args: argparse.Namespace):
    """The detector the command's ``--detector`` (and ``--network-precision``) name, or the ChArUco board's
    (:func:`resolve_board`)."""
    from ccs_kornia.modules.detection.factory import make_detector

    if getattr(args, "charuco_board", None) is not None:
        from ccs_kornia.modules.detection.markers.charuco import CharucoDetector

        return CharucoDetector(args.charuco_board)
    if getattr(args, "aprilgrid_board", None) is not None:
        from ccs_kornia.modules.detection.markers.aprilgrid import AprilGridDetector

        return AprilGridDetector(args.aprilgrid_board)
    options = {}
    if args.detector == "learned" and getattr(args, "network_precision", None):
        options["precision"] = args.network_precision
    try:
        return make_detector(args.detector, **options)
    except ValueError as err:
        raise UserError(str(err)) from None


def pipeline_options(args: argparse.Namespace, use_ransac: bool = True, seed: int = 0) -> dict:
    """The :class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline` options the command's arguments set
    (``--allow-weak``: the solvers keep cameras the views determine only weakly)."""
    options = dict(
        use_ransac=use_ransac, seed=seed, detection_batch_size=args.batch_size,
        workers=getattr(args, "jobs", 1),
        max_detection_side=getattr(args, "max_detection_side", 2048) or None,
        distortion_correction=bool(getattr(args, "distortion_correction", False)),
        diagnostics=bool(getattr(args, "diagnostics", False)),
        weigh_corners=bool(getattr(args, "weigh_corners", True)),
    )
    if getattr(args, "allow_weak", False):
        from ccs_kornia.modules.calibration.quality.degeneracy import (
            DegeneracyThresholds,
        )

        options["thresholds"] = DegeneracyThresholds(refuse_weak=False)
    return options


def weak_lines(data: dict[str, Any]) -> list[str]:
    """What ``--allow-weak`` let through in a camera's record: the checks that would have refused it, and the
    1-sigma of its intrinsics that shows why (empty when nothing was let through)."""
    errors = data.get("errors") or []
    if not data.get("success") or not errors:
        return []
    std = data.get("std") or {}
    K = data["K"]
    sigma = ", ".join(f"{k} {v:.1f} ± {std[k]:.1f}" for k, v in (("fx", K[0][0]), ("fy", K[1][1]), ("cx", K[0][2]),
                                                                   ("cy", K[1][2])) if std.get(k) is not None)
    return [f"calibrated with --allow-weak although {e['message']}" for e in errors] + \
        [f"1-sigma of the intrinsics (px): {sigma}"]


def missing_weights(err: FileNotFoundError) -> UserError:
    """The distortion network's missing weights, as the command line says it."""
    return UserError(str(err).replace("pass distortion_correction=False", "use --no-distortion-correction"))


def make_pipeline(args: argparse.Namespace, model=None, use_ransac: bool = True, seed: int = 0,
                  frame_selection=None):
    """The pipeline of a command: ``model`` a camera model or a ``ModelChoice`` (default ``OPENCV5``)."""
    from ccs_kornia.geometry.models import OPENCV5
    from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline

    model = OPENCV5 if model is None else model

    detector = make_detector_from(args)
    try:
        return CalibrationPipeline(detector, model=model, frame_selection=frame_selection,
                                   **pipeline_options(args, use_ransac, seed))
    except FileNotFoundError as err:
        raise missing_weights(err) from None


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
        from ccs_kornia.io.images import load_image_gray
        from ccs_kornia.modules.detection.checks.board_size import (
            board_size_in,
            other_board_size,
        )

        sizes = []
        for v in views:
            image, _ = load_image_gray(self.cameras[c][v])
            sizes.append(None if image is None else board_size_in(image))
        other = other_board_size(sizes, self.board)
        if other is None:
            return
        shown = sum(1 for s in sizes if s == other)
        if self.board[0] < self.board[1]:  # said the way round the board was given
            other = (other[1], other[0])
        camera = f"camera {self.names[c]}: " if self.names else ""
        raise self.error(f"{camera}board {self.board[0]}x{self.board[1]} not found in the first {len(views)} images, "
                        f"but a {other[0]}x{other[1]} board is in {shown} of them: check --board (COLSxROWS counts "
                        "inner corners, where four squares meet); stopped before the other images")


def run_files(command: str, pipeline, cameras: list[list[str]], board: tuple[int, int], square: float, device,
              calibrate: bool = True, names: list[str] | None = None, source=None):
    """The pipeline's one composition (:meth:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline.run`) on image files, with a
    progress bar; unreadable files are reported on stderr and skipped. ``source``: the views named ``cameras``
    (video frames, :class:`~ccs_kornia.pipeline.sources.VideoSource`) instead of the files.

    Returns:
        ``(result, seconds)``: the batched :class:`~ccs_kornia.pipeline.result.PipelineResult` and the wall time.
    """
    import time

    from tqdm import tqdm

    from ccs_kornia.pipeline.sources import FileSource

    source = FileSource(cameras, names) if source is None else source
    pipeline.to(device)
    start = time.perf_counter()
    total = sum(source.counts)
    with tqdm(total=total, unit="img", desc=command, file=sys.stderr, disable=None, leave=False) as bar:
        def advance(views: int) -> None:
            bar.update(views)
            if bar.n >= total:  # detection done; what follows can take as long (second looks at missed views)
                waiting = f"{'solving; ' if calibrate else ''}second looks at any missed views"
                bar.set_description_str(f"{command}: {waiting}")

        # a plain chessboard's wrong size is named early (a marker board's detector names it itself)
        watch = WrongBoardWatch(cameras, board, names) if getattr(pipeline.detector, "board", None) is None else None
        out = pipeline.run(source, board, square, calibrate=calibrate, progress=advance, on_batch=watch)
    seconds = time.perf_counter() - start
    for c, files in enumerate(cameras):
        reasons = (out.detections.reasons or [""] * out.present.numel())[c * out.present.shape[1]:
                                                                         (c + 1) * out.present.shape[1]]
        load = None if isinstance(source, FileSource) else functools.partial(_grey8, source, c)
        charuco_dictionary_check(pipeline, files, out.detections.found.reshape(out.present.shape)[c], out.present[c],
                                 reasons, load)
    v = out.present.shape[1]
    for c, files in enumerate(cameras):
        for k, path in enumerate(files):
            if not bool(out.present[c, k]):
                warn(command, f"skipped {path}: {out.detections.reasons[c * v + k]}")
    hint = board_size_hint(board, out.detections.reasons or [])
    if hint:
        warn(command, hint)
    return out, seconds


def _grey8(source, camera: int, view: int):
    """View ``view`` of ``camera`` as a grey ``uint8`` array (``None`` where it cannot be read)."""
    image, _ = source._load(camera, view)
    return None if image is None else (image[0].clamp(0, 1) * 255).round().byte().numpy()


def board_size_hint(board: tuple[int, int], reasons: Sequence[str]) -> str:
    """``the board looks larger than 8x6 in N images: check --board ...`` when boards were refused because their
    checker pattern continues past a side (a sub-board of the board in the images); ``""`` otherwise.

    Example:
        >>> board_size_hint((8, 6), ["board refused: the checker pattern continues past its left side", ""])[:49]
        'the board looks larger than 8x6 in 1 image: check'
    """
    n = sum(1 for r in reasons if "continues past" in r)
    if not n:
        return ""
    return (f"the board looks larger than {board[0]}x{board[1]} in {n} image{'s' if n > 1 else ''}: check --board "
            f"(COLSxROWS counts inner corners, where four squares meet)")


#: what to check when a board of each detector is found in no image
_NOT_FOUND_CHECK = {
    "charuco": "check --charuco SXxSY (the squares, as OpenCV's CharucoBoard counts them), --dictionary and --legacy",
    "aprilgrid": "check the target YAML's tagCols and tagRows; the tags must be 36h11 with a two-bit black border, "
                 "as Kalibr prints them",
}


def not_found_message(board: tuple[int, int], readable: int, total: int, detector: str = "") -> str:
    """Why a board was found in no image, with what to check for the board's kind (``detector``).

    Example:
        >>> not_found_message((4, 6), 3, 3, "charuco")[:65]
        'board 4x6 not found in any of 3 images (check --charuco SXxSY (th'
    """
    if readable == 0:
        return f"none of the {total} input files could be read as an image"
    check = _NOT_FOUND_CHECK.get(detector, "check --board: COLSxROWS counts inner corners, where four squares meet")
    return f"board {board[0]}x{board[1]} not found in any of {readable} images ({check})"


def parse_pair(text: str, cameras: int) -> tuple[int, int]:
    """``--pair I,J``: two different cameras of a rig of ``cameras``.

    Example:
        >>> parse_pair("2,0", 4)
        (2, 0)
    """
    parts = text.split(",")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise UserError(f"--pair {text}: expected two camera indices, e.g. 0,1")
    i, j = int(parts[0]), int(parts[1])
    if i == j or max(i, j) >= cameras:
        raise UserError(f"--pair {text}: two different cameras of the {cameras} in the calibration (0..{cameras - 1})")
    return i, j
