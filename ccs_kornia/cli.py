"""Command line: ``python -m ccs_kornia detect|calibrate|calibrate-rig|calibrate-hand-eye|calibrate-imu|imu-noise|compare|rectify|calibrate-many|undistort|demo|fit|...``.

The contract (arguments and JSON layout) is fixed by ``DESIGN.md`` section 4; benchmarks rely on
it. Behaviour on bad input:

* a user mistake that stops the whole job before any result (unknown option, malformed ``--board``, no
  images, none readable, output that cannot be written, ``--device cuda`` without CUDA, a calibration file
  that is not one, ...) prints one line ``ccs_kornia <command>: error: ...`` on stderr and exits with
  status 2 (:data:`EXIT_USAGE`);
* images that were read but gave no result (board found in no image, fewer than 3 usable views, views
  too degenerate to calibrate) print one such line and exit with status 3 (:data:`EXIT_NO_RESULT`);
* a problem with some inputs only (unreadable file, board not found in one image, image of another
  size) prints one ``warning`` line per input, is recorded in the JSON with its reason, and the job
  goes on (status 0);
* an unexpected internal error prints one line and exits with status 1 (``CCS_DEBUG=1`` re-raises
  it with the traceback); Ctrl-C exits with status 130.

Output files (``--output``, ``--opencv-yaml``, ``--ros-yaml``) must go to an existing directory where
files can be written, checked before any work: the parent is not created, so a mistyped path fails at
once instead of scattering results. Output *directories* (``--out-dir``, ``--report``) are created when
missing (``--report`` only once the calibration succeeded). ``calibrate`` writes its JSON only when a
calibration was computed, so a stale or partial file is never mistaken for one; a failed run says so
when it leaves an earlier file at ``--output``. ``docs/command_line.md`` describes all of this.
"""

from __future__ import annotations

import argparse
import atexit
import difflib
import importlib
import os
import re
import sys
import threading
from collections.abc import Sequence
from typing import NoReturn

from ccs_kornia import __version__
from ccs_kornia.commands._printing import PROG
from ccs_kornia.io.boards import parse_board
from ccs_kornia.runtime.allocator import keep_freed_memory
from ccs_kornia.runtime.errors import (
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    EXIT_NO_RESULT,
    EXIT_OK,
    EXIT_USAGE,
    UserError,
)

__all__ = ["main", "run", "build_parser", "UserError", "LIGHTNING_COMMANDS", "EXIT_CODES"]

LIGHTNING_COMMANDS = ("fit", "validate", "test", "predict")
MODELS = ("auto", "opencv5", "rational", "k1k2", "none", "fisheye")
DEFAULT_DETECTOR = "learned"
ALLOW_WEAK_HELP = ("calibrate a camera the views determine only weakly (boards nearly parallel, few corners per "
                   "unknown, a large focal uncertainty) instead of refusing it: the verdict says not reliable, with "
                   "the 1-sigma of the intrinsics that shows why; copies of one view are still refused")


#: the exit statuses, as ``--help`` lists them
EXIT_CODES = (
    (EXIT_OK, "success"),
    (EXIT_INTERNAL, "internal error (CCS_DEBUG=1 shows the traceback)"),
    (EXIT_USAGE, "usage or input error: bad option, no readable images, output not writable, bad calibration file"),
    (EXIT_NO_RESULT, "no result: the board was found in no image, or too few usable views to calibrate"),
    (EXIT_INTERRUPTED, "interrupted (Ctrl-C)"),
)

_EXIT_HELP = "exit status:\n" + "\n".join(f"  {code:<4} {meaning}" for code, meaning in EXIT_CODES)

_NUMBER = re.compile(r"^-\d+$|^-\d*\.\d+$")


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump) and exit status 2; an unknown option is named first.

    argparse checks the required options before it reports unknown ones, so ``--bord 9x6`` read as
    "--board is required"; the arguments seen are kept to name the unknown option instead.
    """

    _seen: list[str] = []

    def parse_known_args(self, args=None, namespace=None):  # type: ignore[override]
        self._seen = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(args, namespace)

    def parse_args(self, args=None, namespace=None):  # type: ignore[override]
        """argparse's, with arguments no command takes reported by the command's parser (``ccs_kornia calibrate:
        error: ...``), not the program's."""
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:
            commands = next((a.choices for a in self._actions if isinstance(a, argparse._SubParsersAction)), {})
            owner = commands.get(getattr(parsed, "command", None), self)
            owner.error(f"unrecognized arguments: {' '.join(extras)}")
        return parsed

    def _unknown_options(self) -> list[str]:
        known = self._option_string_actions
        out = []
        for token in self._seen:
            if token == "--":
                break
            name = token.split("=", 1)[0]
            if not name.startswith("-") or name == "-" or _NUMBER.match(name) or name in known:
                continue
            if name.startswith("--") and any(o.startswith(name) for o in known if o.startswith("--")):
                continue  # an abbreviation argparse accepts (or reports as ambiguous itself)
            out.append(name)
        return out

    def error(self, message: str) -> None:  # type: ignore[override]
        if message.startswith("one of the arguments --board --charuco"):
            tag = ", --apriltag FAMILY (a single AprilTag)" if "--apriltag" in message else ""
            message = ("the following arguments are required: --board COLSxROWS (a chessboard's inner corners), "
                       f"--charuco SXxSY (a ChArUco board's squares){tag}, --aprilgrid TARGET_YAML (Kalibr's "
                       "AprilGrid) or --circles COLSxROWS (a circle grid's dots)")
        named = message.startswith(("the following arguments are required", "unrecognized arguments"))
        unknown = self._unknown_options() if named else []
        if unknown:
            long_options = [o for o in self._option_string_actions if o.startswith("--")]
            close = difflib.get_close_matches(unknown[0], long_options, n=1)
            hint = f" (did you mean {close[0]}?)" if close else ""
            message = f"unrecognized option{'s' if len(unknown) > 1 else ''} {' '.join(unknown)}{hint}"
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see --help)\n")


# ----------------------------------------------------------------------------------------------
# argument types
# ----------------------------------------------------------------------------------------------


def _board_arg(text: str) -> tuple[int, int]:
    try:
        return parse_board(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _checked_number(convert, accept, expected: str):
    """An argparse type: ``text`` converted by ``convert`` (``int`` or ``float``) and kept where ``accept(value)``;
    otherwise one line, "expected <expected>, got <text>", as argparse prints its errors.

    Example:
        >>> _checked_number(int, lambda v: v > 2, "more than 2")("3")
        3
    """

    def parse(text: str):
        try:
            value = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if not accept(value):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text}")
        return value

    return parse


_positive_int = _checked_number(int, lambda v: v >= 1, "a positive integer")
_detection_side = _checked_number(int, lambda v: v == 0 or v >= 64, "0 (off) or at least 64")
_view_angle = _checked_number(float, lambda v: 0.0 < v < 180.0, "an angle in degrees between 0 and 180")
_positive_float = _checked_number(float, lambda v: 0 < v < float("inf"), "a positive number")
_unit_float = _checked_number(float, lambda v: 0.0 <= v <= 1.0, "a number in [0, 1]")


#: the sizes a board's square, marker or tag may have, in any unit (metres to millimetres and beyond): outside it the
#: solver's arithmetic under- or overflows
LENGTH_RANGE = (1e-6, 1e6)


def _length_arg(text: str) -> float:
    """A board's size (``--square``, ``--marker``, ``--tag-size``): a positive number within :data:`LENGTH_RANGE`."""
    value = _positive_float(text)
    low, high = LENGTH_RANGE
    if not low <= value <= high:
        raise argparse.ArgumentTypeError(f"expected a size between {low:g} and {high:g} in the board's unit (metres, "
                                         f"millimetres, ...), got {text}")
    return value


def _device_arg(text: str) -> str:
    if text == "cpu" or text == "cuda" or (text.startswith("cuda:") and text[5:].isdigit()):
        return text
    raise argparse.ArgumentTypeError(f"invalid device {text!r}: expected cpu, cuda or cuda:N")


def _jobs_arg(text: str) -> int | str:
    if text == "auto":
        return text
    try:
        return _positive_int(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"invalid --jobs {text!r}: expected a positive integer or auto") from None


def _circles_arg(text: str) -> tuple[int, int]:
    parts = str(text).strip().lower().split("x")
    if len(parts) != 2 or not all(q.strip().isdigit() for q in parts):
        raise argparse.ArgumentTypeError(f"invalid circle grid {text!r}: expected COLSxROWS dots, as OpenCV's "
                                         "findCirclesGrid counts them, e.g. 4x11")
    cols, rows = (int(q) for q in parts)
    if min(cols, rows) < 2 or cols * rows < 6:
        raise argparse.ArgumentTypeError(f"invalid circle grid {text!r}: at least 2 dots a side and 6 in all")
    return cols, rows


def _squares_arg(text: str) -> tuple[int, int]:
    try:
        sx, sy = parse_board(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid ChArUco board {text!r}: expected SQUARES_XxSQUARES_Y, the squares "
                                         "as OpenCV's CharucoBoard counts them, e.g. 5x7") from None
    if min(sx, sy) < 3:
        raise argparse.ArgumentTypeError(f"invalid ChArUco board {text!r}: at least 3x3 squares")
    return sx, sy


def charuco_options(p: argparse.ArgumentParser, which, square: bool = False) -> None:
    """``--charuco SXxSY`` (in ``which``, the group of ``--board``) ``--dictionary D --marker M
    [--legacy/--no-legacy]``, ``--aprilgrid TARGET_YAML``, ``--circles COLSxROWS --spacing S [--asymmetric]
    [--marked-origin] [--diameter D]`` (and ``--square`` where the command has none)."""
    g = p.add_argument_group("ChArUco boards (instead of --board)")
    which.add_argument("--charuco", type=_squares_arg, metavar="SXxSY",
                   help="a ChArUco board of SX x SY squares, as OpenCV's CharucoBoard((SX, SY), ...): its (SX-1) x "
                        "(SY-1) inner corners are identified by the markers, so boards cut by the image's frame count")
    g.add_argument("--dictionary", default="DICT_6X6_250", metavar="DICT",
                   help="its ArUco dictionary, OpenCV's name (default DICT_6X6_250)")
    g.add_argument("--marker", type=_length_arg, metavar="SIDE",
                   help="its marker side, in the unit of --square (required with --charuco)")
    g.add_argument("--legacy", action=argparse.BooleanOptionalAction, default=None,
                   help="OpenCV's legacy layout (before 4.6) or not; default: found on each image (boards of an even "
                        "number of rows of squares differ)")
    which.add_argument("--aprilgrid", metavar="TARGET_YAML",
                       help="Kalibr's AprilGrid, as its target YAML gives it (target_type: aprilgrid, tagCols, tagRows, "
                            "tagSize, tagSpacing): corners numbered as Kalibr does, identified by the tags (boards cut "
                            "by the frame count); world units are tagSize's")
    c = p.add_argument_group("circle grids (instead of --board)")
    which.add_argument("--circles", type=_circles_arg, metavar="COLSxROWS",
                       help="a grid of COLS x ROWS dots as OpenCV's findCirclesGrid counts them (patternSize), dark "
                            "dots on light or the inverse; their centres corrected for perspective and lens distortion "
                            "once the camera is known")
    c.add_argument("--spacing", type=_length_arg, metavar="S",
                   help="distance between neighbouring dots' centres, world units (required with --circles; "
                        "--asymmetric: OpenCV's squareSize, half the distance between the dots of one row)")
    c.add_argument("--asymmetric", action="store_true",
                   help="OpenCV's asymmetric grid (every other row shifted by half a pitch)")
    c.add_argument("--marked-origin", action="store_true",
                   help="ROS-Industrial's modified circle grid: one dot twice the others' diameter marks the origin "
                        "(dot 0; x along its row, y up its column), which fixes the grid's orientation")
    c.add_argument("--diameter", type=_length_arg, metavar="D",
                   help="the (small) dots' diameter, in the unit of --spacing (default: half the distance between "
                        "neighbouring dots)")
    if square:
        g.add_argument("--square", default=1.0, type=_length_arg,
                       help="its square side (only the ratio to --marker matters here; default 1)")


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds (a number >= 0), got {text!r}") from None
    if not 0.0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected seconds (a number >= 0), got {text}")
    return value


def video_options(p: argparse.ArgumentParser, rig: bool = False, selection: bool = True) -> None:
    """``--every N --start S --end S --max-frames N --max-motion PX`` for recordings given instead of images (and, for a rig,
    ``--sync-tolerance S --timestamps CSV``); ``selection``: the command has the frame selection (``--select``)."""
    g = p.add_argument_group("videos (mp4, mkv, avi, mov, mjpeg, ... instead of images)")
    g.add_argument("--every", default=1, type=_positive_int, metavar="N",
                   help="screen every N-th frame only (default 1: every frame)")
    g.add_argument("--start", type=_seconds, metavar="S", help="first frame at S seconds (default: the start)")
    g.add_argument("--end", type=_seconds, metavar="S", help="last frame at S seconds (default: the end)")
    g.add_argument("--max-frames", default=None, type=_positive_int, metavar="N",
                   help="frames of a recording (instants of a rig) kept at most (default 60): still boards (moving "
                        "at most 0.1 %% of the image diagonal a frame) are chosen after a quick screening of every "
                        "frame, poses not seen yet first, then more frames of the still poses" +
                        ("; with the frame selection (--select) the detector looks at up to 1.5 times as many and "
                         "the best are kept" if selection else ""))
    g.add_argument("--max-motion", default=None, type=_positive_float, metavar="PX",
                   help="where the still frames do not cover the poses (their boards within 20 deg of each other), "
                        "moving frames are taken too, least motion first: those whose board moves at most PX a frame "
                        "(default 1 %% of the image diagonal)")
    if rig:
        g.add_argument("--sync-tolerance", type=_positive_float, metavar="S",
                       help="frames of two cameras pair when their timestamps differ by at most S seconds (default: "
                            "half the shortest frame period)")
        g.add_argument("--timestamps", metavar="CSV",
                       help="pair the frames as this table says: sync_index,cam_id,frame_index,frame_time per row "
                            "(caliscope's layout; cam_id = the video's position on the command line; without "
                            "frame_index a camera's rows are its frames in order)")


def corner_options(p: argparse.ArgumentParser, rig: bool, corners: bool = True) -> None:
    """``--corners JSON [--image-size WxH]`` (corners detected before, instead of images; where ``corners``) and
    ``--bag BAG --image-topics TOPIC[,TOPIC...]`` (a ROS bag's images)."""
    g = p.add_argument_group("corners detected before, or a ROS bag (instead of images)" if corners else
                             "a ROS bag (instead of images)")
    if corners:
        _corners_file_options(g, rig)
    g.add_argument("--bag", metavar="BAG",
                   help="a ROS1 (.bag) or ROS2 (folder with metadata.yaml, or .db3 / .mcap) bag: the images of "
                        "--image-topics as a recording (frames named BAG#TOPIC#INDEX, with their header stamps as "
                        "timestamps), read without ROS")
    g.add_argument("--image-topics", metavar="TOPIC[,TOPIC...]",
                   help="the bag's image topics (sensor_msgs/Image or CompressedImage)" +
                        (", one per camera in the rig's order" if rig else ", one"))


def _corners_file_options(g, rig: bool) -> None:
    g.add_argument("--corners", action="append", metavar="JSON",
                   help=("the corners file detect wrote, one per camera in the rig's order (repeat --corners); views "
                         "match across cameras by their timestamps where every view has one, else by the last number "
                         "in their names" if rig else "the corners file detect wrote, or mrcal's corners.vnl (with --image-size)") +
                        ": the solve runs on its corners, nothing is detected again; the board options still say the "
                        "board and its square size (a file of another board is refused)")
    g.add_argument("--image-size", metavar="WxH",
                   help="the images' size, for a corners file that does not say it (written before detect recorded it)")


def selection_options(p: argparse.ArgumentParser) -> None:
    """``--select/--no-select`` and ``--save-frames DIR``."""
    g = p.add_argument_group("frame selection")
    g.add_argument("--select", action=argparse.BooleanOptionalAction, default=None,
                   help="keep only the frames that make the best camera: still and sharp, new poses before near "
                        "copies of kept ones, taken by how much each lowers the predicted projection uncertainty "
                        "(--max-frames caps them; the JSON's selection says why each other frame was left out). "
                        "Default: off")
    g.add_argument("--save-frames", metavar="DIR",
                   help="with --select: also write the frames it kept as images to DIR (created; a rig's in one "
                        "folder per camera): the same set can be calibrated again as a folder")


def detection_options(p: argparse.ArgumentParser) -> None:
    """The detector's options of a command that detects boards but is not about the boards (``--detector --device
    --jobs --batch-size --max-detection-side --no-distortion-correction``)."""
    p.add_argument("--detector", default=DEFAULT_DETECTOR, choices=("learned", "opencv"))
    p.add_argument("--device", default="cpu", type=_device_arg, help="cpu, cuda or cuda:N (default: cpu)")
    p.add_argument("--jobs", default="auto", type=_jobs_arg, metavar="N",
                   help="processes detecting on the CPU (default: auto; 1 = this process only)")
    p.add_argument("--batch-size", default=8, type=_positive_int, metavar="N", help="images detected at once (default 8)")
    p.add_argument("--max-detection-side", default=2048, type=_detection_side, metavar="PX",
                   help="detect larger images on a downscaled copy (default 2048; 0 = off)")
    p.add_argument("--no-distortion-correction", dest="distortion_correction", action="store_false",
                   help="do not run the distortion-correction network")


def calibrate_options(p: argparse.ArgumentParser) -> None:
    """What ``calibrate`` and ``capture`` both take once the board and the inputs are said: ``--square --output
    --model --no-ransac --seed --unweighted --report --opencv-yaml --ros-yaml --no-distortion-correction
    --no-diagnostics --allow-weak``."""
    p.add_argument("--square", default=1.0, type=_length_arg,
                   help="square side in world units (scales the poses only; default 1)")
    p.add_argument("--output", required=True, metavar="JSON",
                   help="calibration file to write, only when a calibration was computed: a failed run leaves an "
                        "earlier file there as it was (and says so) and writes its per-image results to "
                        "JSON.failed.json, which a later successful run removes")
    p.add_argument("--model", default="auto", choices=(*MODELS, "splined"),
                   help="camera model: auto (default: k1k2, opencv5, rational or fisheye, chosen by cross-validation "
                        "on held-out views; the JSON says which and why), opencv5 (k1,k2,p1,p2,k3), rational (k1..k6), "
                        "k1k2, none, fisheye (Kannala-Brandt k1..k4, as cv2.fisheye), splined (mrcal's splined "
                        "stereographic model fitted from auto's choice, its grid from the image and the corners)")
    p.add_argument("--no-ransac", dest="use_ransac", action="store_false", help="keep every detected view")
    p.add_argument("--seed", default=0, type=int, help="RANSAC seed (default 0)")
    p.add_argument("--unweighted", dest="weigh_corners", action="store_false",
                   help="count every corner equally (the plain least-squares fit, as cv2.calibrateCamera: the lowest "
                        "RMS; by default corners are weighted by the precision measured on their image, which gives "
                        "more accurate cameras and a slightly higher RMS)")
    p.add_argument("--report", metavar="DIR",
                   help="also write overlays and a summary to DIR (created once the calibration succeeded; the files "
                        "of an earlier report there are replaced, other files are left alone)")
    p.add_argument("--opencv-yaml", metavar="FILE", help="also write an OpenCV FileStorage YAML (camera_matrix, ...)")
    p.add_argument("--ros-yaml", metavar="FILE", help="also write a ROS camera_info YAML (distortion_model plumb_bob, "
                   "rational_polynomial or equidistant for fisheye)")
    p.add_argument("--no-distortion-correction", dest="distortion_correction", action="store_false",
                   help="do not run the distortion-correction network (strongly distorted lenses are then "
                        "calibrated by the joint refinement alone)")
    p.add_argument("--no-diagnostics", dest="diagnostics", action="store_false",
                   help="skip the quality figures (cross-validation of two halves of the views, held-out views, "
                        "projection uncertainty) and the verdict; they cost a few more solves")
    p.add_argument("--flat-board", dest="board_flatness", action="store_false",
                   help="take the board as flat: do not fit its sag (mrcal's two-parameter bend, kept where held-out "
                        "views say it helps; a few more solves)")
    p.add_argument("--allow-weak", action="store_true", help=ALLOW_WEAK_HELP)


def build_parser() -> argparse.ArgumentParser:
    """The argparse parser of every command except the Lightning ones (forwarded untouched)."""
    parser = _Parser(
        prog=PROG,
        description="Camera calibration from chessboard images (batched PyTorch/Kornia).",
        epilog="Training: python -m ccs_kornia fit|validate|test|predict --config lightning_configs/<x>.yaml "
        "(LightningCLI; see its --help).\n\n" + _EXIT_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    def common(p: argparse.ArgumentParser, board: bool = True, square: bool = False, corners: bool = False,
               selection: bool = False, files: bool = True) -> None:
        if files:
            p.add_argument("images", nargs="*" if board else "+", metavar="IMAGES",
                           help="image files, directories or globs" + (", or videos (one camera's recordings)" if board
                                                                        else "") + (" (or --corners, --bag)" if corners
                                                                                    else " (or --bag)" if board else ""))
        if board and files:
            corner_options(p, rig=False, corners=corners)
        if board:
            which = p.add_mutually_exclusive_group(required=True)
            which.add_argument("--board", type=_board_arg, metavar="COLSxROWS",
                               help="inner corners per row x rows of inner corners, e.g. 9x6 (or --charuco)")
            p.add_argument("--detector", default=DEFAULT_DETECTOR, choices=("learned", "opencv"),
                           help=f"corner detector (default: {DEFAULT_DETECTOR}; a --charuco board has its own)")
            charuco_options(p, which, square=square)
        p.add_argument("--device", default="cpu", type=_device_arg, help="cpu, cuda or cuda:N (default: cpu)")
        if board:
            p.add_argument("--batch-size", default=8, type=_positive_int, metavar="N",
                           help="images loaded and processed at once by each process (default: 8; fewer when "
                                "images are large: at most 16 Mpx per batch)")
            p.add_argument("--jobs", default="auto", type=_jobs_arg, metavar="N",
                           help="processes detecting on the CPU, one thread each (default: auto, one per core, at "
                                "most 4; 1 = this process only); any number gives the same corners")
            p.add_argument("--max-detection-side", default=2048, type=_detection_side, metavar="PX",
                           help="detect on a downscaled copy of larger images, then refine corners at full "
                                "resolution (default: 2048; 0 = always full resolution)")
            p.add_argument("--network-precision", default="float32", choices=("float32", "bfloat16", "auto"),
                           help="the learned detector's heatmap network: float32 (default: the same corners on every "
                                "machine), bfloat16 (about 1.7x faster on CPUs with native bfloat16, AVX512-BF16 or "
                                "AMX, slower elsewhere; can find other boards), auto (bfloat16 where native)")
            if files:
                video_options(p, selection=selection)

    p = sub.add_parser("detect", help="detect chessboard corners, write them as JSON", epilog=_EXIT_HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    common(p, square=True)
    p.add_argument("--output", required=True, metavar="JSON", help="corners file to write")
    p.add_argument("--no-distortion-correction", dest="distortion_correction", action="store_false",
                   help="detect on the images as they are (by default a strongly distorted lens's images are "
                        "corrected for detection; corners are always given in the original images)")

    p = sub.add_parser("calibrate", help="calibrate a camera from chessboard images", epilog=_EXIT_HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    common(p, corners=True, selection=True)
    calibrate_options(p)
    selection_options(p)

    p = sub.add_parser("capture", help="calibrate a camera at hand: hold the board where it says, the frames that lower "
                       "the predicted uncertainty are kept, the camera calibrated when the target is reached",
                       epilog=_EXIT_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("sources", nargs="+", metavar="SOURCE",
                   help="a camera index (0), a device (/dev/video0), a stream URL (rtsp://, http://) or a video file "
                        "(played at its own rate); several make a rig (--output rig.json, calibrated as calibrate-rig "
                        "would)")
    common(p, files=False)
    calibrate_options(p)
    g = p.add_argument_group("capture")
    g.add_argument("--frames-dir", metavar="DIR",
                   help="write the kept frames here (created; must be empty): calibrate DIR gives the same camera "
                        "(default: the output's name without .json, then _frames)")
    g.add_argument("--target", default=0.1, type=_positive_float, metavar="PX",
                   help="done when the predicted worst 1-sigma projection uncertainty over the image is at most PX "
                        "(default 0.1)")
    g.add_argument("--max-frames", default=40, type=_positive_int, metavar="N",
                   help="done at N kept frames whatever the figure (default 40)")
    g.add_argument("--fast", action="store_true",
                   help="read a video file as fast as it decodes (default: at its own rate, as a camera gives it)")
    g.add_argument("--port", default=8765, type=int, metavar="PORT",
                   help="the page's port: http://127.0.0.1:PORT shows the live image, the coverage, the uncertainty "
                        "map, the next pose and the kept frames (default 8765; 0: any free port)")
    g.add_argument("--host", default="127.0.0.1", metavar="HOST",
                   help="the interface the page listens on (default 127.0.0.1: this machine only; 0.0.0.0: every "
                        "interface)")
    g.add_argument("--no-page", action="store_true", help="no page: the console only")
    g.add_argument("--page-linger", default=10.0, type=float, metavar="S",
                   help="keep the page up S seconds after calibrating, showing the verdict and the held-out figure "
                        "(default 10; 0: close at once; Ctrl-C ends it early, the files are written)")

    p = sub.add_parser("calibrate-rig", help="calibrate a rig of cameras (stereo head, multi-camera robot) from one "
                       "folder of board images per camera", epilog=_EXIT_HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("cameras", nargs="*", metavar="CAM_DIR",
                   help="one folder (or quoted glob) of images per camera; views match across cameras by the last number "
                        "in the file names (left07.jpg with right07.jpg), else by sorted order; or one video per "
                        "camera, frames paired by timestamp (--sync-tolerance), by --timestamps, else by index "
                        "(or --corners per camera, --bag)")
    corner_options(p, rig=True)
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--board", type=_board_arg, metavar="COLSxROWS", help="inner corners, e.g. 9x6 (or --charuco)")
    p.add_argument("--square", default=1.0, type=_length_arg,
                   help="square side in world units: the unit of the baselines (metres for ROS and Kalibr; default 1)")
    charuco_options(p, which)
    p.add_argument("--output", required=True, metavar="JSON", help="rig calibration file to write (rig.json)")
    p.add_argument("--model", default="auto", metavar="MODEL[,MODEL...]",
                   help=f"camera model, one for all cameras or one per camera ({', '.join(MODELS)}; default auto: "
                        "each camera's model chosen by cross-validation as calibrate does)")
    p.add_argument("--names", metavar="NAME,NAME...", help="camera names (default cam0,cam1,...; ROS file names)")
    p.add_argument("--fix-intrinsics", action="append", metavar="CAM_INDEX=JSON",
                   help="keep camera CAM_INDEX's intrinsics as a calibrate JSON gives them (repeatable)")
    p.add_argument("--opencv-yaml", metavar="FILE", help="also write the pair of --pair as an OpenCV FileStorage YAML "
                   "(K1 D1 K2 D2 R T E F R1 R2 P1 P2 Q)")
    p.add_argument("--ros-yaml-dir", metavar="DIR", help="also write the pair of --pair as ROS stereo camera_info "
                   "files, named after the cameras (cam0.yaml, cam1.yaml, or the --names)")
    p.add_argument("--pair", metavar="I,J", help="the cameras of the stereo files and of the report's rectified pair "
                   "(default 0,1; required for --opencv-yaml and --ros-yaml-dir with more than two cameras)")
    p.add_argument("--kalibr-yaml", metavar="FILE", help="also write a Kalibr camchain YAML")
    p.add_argument("--report", metavar="DIR", help="also write figures (error per camera and frame, a rectified "
                   "pair, the rig from above) to DIR (created)")
    p.add_argument("--detector", default=DEFAULT_DETECTOR, choices=("learned", "opencv"))
    p.add_argument("--device", default="cpu", type=_device_arg, help="cpu, cuda or cuda:N (default: cpu)")
    p.add_argument("--jobs", default="auto", type=_jobs_arg, metavar="N",
                   help="processes detecting on the CPU (default: auto; 1 = this process only)")
    p.add_argument("--batch-size", default=8, type=_positive_int, metavar="N", help="images detected at once (default 8)")
    p.add_argument("--max-detection-side", default=2048, type=_detection_side, metavar="PX",
                   help="detect larger images on a downscaled copy (default 2048; 0 = off)")
    p.add_argument("--network-precision", default="float32", choices=("float32", "bfloat16", "auto"),
                   help="the learned detector's network precision (see calibrate --help)")
    p.add_argument("--no-ransac", dest="use_ransac", action="store_false", help="keep every detected view")
    p.add_argument("--seed", default=0, type=int, help="RANSAC seed (default 0)")
    p.add_argument("--unweighted", dest="weigh_corners", action="store_false",
                   help="count every corner equally (by default corners are weighted by their measured precision)")
    p.add_argument("--no-distortion-correction", dest="distortion_correction", action="store_false",
                   help="do not run the distortion-correction network")
    p.add_argument("--flat-board", dest="board_flatness", action="store_false",
                   help="take the board as flat: do not fit its sag with the rig (mrcal's two-parameter bend, kept "
                        "where the held-out epipolar RMS says it helps; one more joint fit)")
    p.add_argument("--allow-weak", action="store_true", help=ALLOW_WEAK_HELP)
    video_options(p, rig=True)
    selection_options(p)
    p.set_defaults(model_choices=MODELS)

    p = sub.add_parser("calibrate-hand-eye", help="where a camera sits on a robot (eye-in-hand or eye-to-hand), "
                       "from board images and the robot's pose of each image", epilog=_EXIT_HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("images", nargs="+", metavar="IMAGES", help="image files, directories or globs")
    p.add_argument("--robot-poses", required=True, metavar="CSV",
                   help="one row per image: its file name, then the flange's pose in the base frame (x_base = T "
                        "x_flange): x,y,z,qx,qy,qz,qw or x,y,z,rx,ry,rz (radians) or a 4x4 matrix row by row")
    mount = p.add_mutually_exclusive_group(required=True)
    mount.add_argument("--eye-in-hand", action="store_true", help="the camera rides on the flange (X: flange -> camera)")
    mount.add_argument("--eye-to-hand", action="store_true", help="the camera stands still, the board rides on the "
                       "flange (X: base -> camera)")
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--board", type=_board_arg, metavar="COLSxROWS", help="a chessboard's inner corners, e.g. 9x6")
    p.add_argument("--square", default=1.0, type=_length_arg,
                   help="the board's square side in metres (the robot poses' unit once read)")
    charuco_options(p, which)
    which.add_argument("--apriltag", choices=("36h11", "36h10", "25h9", "16h5"), metavar="FAMILY",
                       help="a single AprilTag of this family (36h11, ...) as the target; needs --tag-size and "
                            "--calibration")
    p.add_argument("--tag-size", type=_length_arg, metavar="M", help="the tag's black square side in metres")
    p.add_argument("--tag-id", type=int, metavar="ID", help="the tag's id (default: the one found in most images)")
    p.add_argument("--pose-format", default="auto", choices=("auto", "quat", "quat-wxyz", "rotvec", "matrix"),
                   help="the poses' form (default auto: by the count of numbers per row; 7 numbers are quat, x,y,z,"
                        "qx,qy,qz,qw; quat-wxyz is scalar first, x,y,z,qw,qx,qy,qz)")
    p.add_argument("--pose-units", default="m", choices=("m", "mm"), help="the poses' translations (default m)")
    p.add_argument("--calibration", metavar="JSON",
                   help="the camera (a calibrate JSON); default: calibrated from the same images")
    p.add_argument("--model", default="auto", choices=MODELS,
                   help="camera model when the camera is calibrated from the images (default auto)")
    p.add_argument("--refine-intrinsics", action="store_true",
                   help="fit the camera's intrinsics in the hand-eye fit too (default: held)")
    p.add_argument("--robot-noise", default="auto", metavar="auto|none|DEG,MM",
                   help="the robot poses' 1-sigma: auto (default: estimated from the data, or another model of the "
                        "robot's error where it predicts held-out poses better), none (exact poses) or DEG,MM")
    p.add_argument("--flat-board", dest="board_flatness", action="store_false",
                   help="take the board as flat: do not fit its sag with X (mrcal's two-parameter bend, kept where "
                        "held-out poses say it helps; one more fit, and the held-out refits where the poses "
                        "determine it)")
    p.add_argument("--output", required=True, metavar="JSON", help="hand-eye calibration file to write (handeye.json)")
    p.add_argument("--ros-tf", metavar="FILE", help="also write a ROS launch file with the static transform")
    p.add_argument("--moveit-yaml", metavar="FILE", help="also write the calibration YAML easy_handeye and MoveIt set-ups "
                   "load")
    p.add_argument("--ros-frames", default="base_link,tool0,camera_optical_frame", metavar="BASE,FLANGE,CAMERA",
                   help="frame names of --ros-tf and --moveit-yaml (default base_link,tool0,camera_optical_frame)")
    p.add_argument("--report", metavar="DIR", help="also write figures (each pose's board predicted from the robot "
                   "alone, residuals by pose, the camera and board in the robot's frame) to DIR (created)")
    detection_options(p)

    p = sub.add_parser("calibrate-imu", help="where an IMU sits on a camera (or rig) and the time offset between "
                       "their clocks, from one recording", epilog=_EXIT_HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("inputs", nargs="*", metavar="CAMERA_INPUT",
                   help="one video or one folder of images per camera (in the rig's order): a video's frame times "
                        "are its container's, on the IMU's clock; each image named by its timestamp in nanoseconds "
                        "(EuRoC's and Kalibr's layout: cam0/data/1403636579763555584.png); or none with --corners")
    p.add_argument("--frame-rate", default=20.0, type=_positive_float, metavar="HZ",
                   help="a video's frames showing the board detected at most HZ per second (default 20; the IMU "
                        "carries the motion between them)")
    p.add_argument("--timestamps", action="append", metavar="CSV",
                   help="for a folder of images not named by their time: a table of its file names and timestamps "
                        "(EuRoC's data.csv, or name,time rows; ns or s, told by the header or the spacing), one per "
                        "folder in order (repeat the option)")
    p.add_argument("--start", type=_seconds, metavar="S", help="a video's first frame at S seconds (default: the start)")
    p.add_argument("--end", type=_seconds, metavar="S", help="a video's last frame at S seconds (default: the end)")
    p.add_argument("--corners", action="append", metavar="JSON",
                   help="the corners detect wrote, one file per camera in the rig's order (repeat the option), each "
                        "view with its timestamp: detection is not repeated")
    p.add_argument("--bag", metavar="BAG",
                   help="a ROS1 or ROS2 bag holding the recording (read with rosbags, no ROS install): its "
                        "--image-topics and --imu-topic")
    p.add_argument("--image-topics", metavar="TOPIC[,TOPIC]", help="the bag's image topics, one per camera in order")
    p.add_argument("--imu-topic", metavar="TOPIC", help="the bag's sensor_msgs/Imu topic (instead of --imu)")
    p.add_argument("--imu", metavar="CSV",
                   help="the IMU's samples: timestamp (ns, or s), wx,wy,wz (rad/s), ax,ay,az (m/s^2), EuRoC's layout "
                        "(a header or none; deg/s and g are caught and converted)")
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--board", type=_board_arg, metavar="COLSxROWS", help="a chessboard's inner corners, e.g. 9x6")
    p.add_argument("--square", default=1.0, type=_positive_float, help="the board's square side in metres")
    charuco_options(p, which)
    p.add_argument("--calibration", action="append", metavar="FILE",
                   help="the cameras: calibrate's JSON (one per camera, repeat the option), a calibrate-rig JSON or "
                        "Kalibr's camchain.yaml (held in the fit); default: each camera calibrated first from up to 40 "
                        "of its own frames")
    p.add_argument("--model", default="opencv5", choices=[m for m in MODELS if m != "auto"],
                   help="camera model when a camera is calibrated from the recording (no --calibration; default "
                        "opencv5, Kalibr's pinhole-radtan)")
    p.add_argument("--imu-yaml", metavar="YAML",
                   help="the IMU's noise as Kalibr's imu.yaml states it (default: EuRoC's ADIS16448; either way each "
                        "sensor's white noise is then measured from the recording)")
    p.add_argument("--output", required=True, metavar="JSON", help="camera-IMU calibration file to write (imu_cam.json)")
    p.add_argument("--kalibr-yaml", metavar="YAML", help="also write Kalibr's camchain-imucam.yaml")
    p.add_argument("--kalibr-imu-yaml", metavar="YAML",
                   help="also write the IMU as Kalibr's calibration does (imu-*.yaml: the noise the recording shows, "
                        "the model and, with --imu-model scale-misalignment, its matrices in Kalibr's convention)")
    p.add_argument("--ros-tf", metavar="FILE", help="also write a ROS launch file publishing each camera's optical "
                   "frame in the IMU's frame (static transforms)")
    p.add_argument("--ros-frames", metavar="IMU[,CAM0,...]",
                   help="frame names of --ros-tf: the IMU's, then each camera's (default imu, then "
                        "<camera name>_optical_frame)")
    p.add_argument("--imu-model", default="calibrated", choices=("calibrated", "scale-misalignment"),
                   help="calibrated (default): the IMU reads the true rate and force (plus biases and noise); "
                        "scale-misalignment: its scale factors, axis misalignment and the gyroscope's g-sensitivity "
                        "are fitted too (written as imu_intrinsics with their 1-sigma)")
    p.add_argument("--refine-intrinsics", action="store_true",
                   help="refine the cameras' parameters in the fit too (from --calibration's; written as "
                        "camera_refined with their 1-sigma); default: held")
    p.add_argument("--refine-rig", action="store_true",
                   help="with a rig calibration (calibrate-rig JSON, camchain with T_cn_cnm1): fit each camera's "
                        "T_cam_imu on its own and say how far the rig they imply is from the calibrated one (default: "
                        "the rig's extrinsics held, camera 0's T_cam_imu fitted, the others following it)")
    p.add_argument("--report", metavar="DIR", help="also write figures (the gyroscope and accelerometer against the "
                   "fitted trajectory, the corners' residuals, the time-offset search) to DIR (created)")
    p.add_argument("--max-shift", default=0.2, type=_positive_float, metavar="S",
                   help="search the time offset within +-S seconds (default 0.2)")
    p.add_argument("--align-clocks", action="store_true",
                   help="the cameras' and the IMU's clocks start from different origins (a video's from 0, an IMU "
                        "log's from the epoch): find each camera's offset from the angular speeds over the whole "
                        "recordings first, then search --max-shift about it")
    p.add_argument("--rolling-shutter", action="store_true",
                   help="the cameras read their rows one after the other: each corner is fitted at its row's time and "
                        "each camera's row delay is estimated (written as line_delay_s)")
    p.add_argument("--knot-spacing", default=0.02, type=_positive_float, metavar="S",
                   help="the IMU trajectory's knot spacing in seconds (default 0.02)")
    p.add_argument("--flat-board", dest="board_flatness", action="store_false",
                   help="take the board as flat: do not fit its sag with T_cam_imu (mrcal's two-parameter bend, kept "
                        "where frames left out of the fit are predicted better with it; one more fit, and two fits "
                        "without every other frame where the frames determine it)")
    detection_options(p)
    p = sub.add_parser("imu-noise", help="an IMU's noise from a still log: the Allan deviation, Kalibr's imu.yaml",
                       description="The Allan deviation of each axis of a still IMU log (the IMU at rest, an hour or "
                                   "more), and Kalibr's four noise values read off it: the white noise density on the "
                                   "-1/2 slope line at 1 s, the bias random walk on the +1/2 slope line at 3 s (the "
                                   "mean of the three axes is written).",
                       epilog=_EXIT_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("log", metavar="IMU_CSV",
                   help="the still log: a CSV of timestamp (ns or s, told by the magnitude), wx, wy, wz (rad/s) and "
                        "ax, ay, az (m/s^2); EuRoC's header, a plain header naming the columns, or none; deg/s and g "
                        "are caught and converted")
    p.add_argument("--output", required=True, metavar="YAML", help="Kalibr's imu.yaml to write")
    p.add_argument("--plot", metavar="PNG", help="also write the Allan deviation figure")
    p.add_argument("--rostopic", default="/imu0", metavar="TOPIC", help="the rostopic written in imu.yaml (default "
                   "/imu0; Kalibr reads it)")

    p = sub.add_parser("compare", help="how far two calibrations of one camera project the same ray apart, over the "
                       "image, beside what their uncertainty explains",
                       description="The ray the first calibration sees at each pixel of a grid, projected by the "
                                   "second, the rotation between the two camera frames fitted out where both saw "
                                   "boards (mrcal's projection difference); with the difference their 1-sigma "
                                   "predict where the files record it.",
                       epilog=_EXIT_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("first", metavar="CALIB_A", help="a calibration JSON (calibrate's, or a rig.json with --camera)")
    p.add_argument("second", metavar="CALIB_B", help="another calibration of the same camera")
    p.add_argument("--camera", metavar="NAME", help="the camera of rig files (its name or index)")
    p.add_argument("--output", metavar="JSON", help="also write the figures and the grids of differences")
    p.add_argument("--plot", metavar="PNG", help="also write the difference over the image (and the expected one)")

    p = sub.add_parser("rectify", help="rectify stereo image pairs with a rig calibration")
    p.add_argument("left", metavar="LEFT_IMAGES", help="folder or glob of the first camera's images")
    p.add_argument("right", metavar="RIGHT_IMAGES", help="folder or glob of the second camera's images")
    p.add_argument("--calibration", required=True, metavar="JSON", help="rig.json written by calibrate-rig")
    p.add_argument("--out-dir", required=True, metavar="DIR", help="where to write the rectified images (created)")
    p.add_argument("--pair", default="0,1", metavar="I,J", help="the cameras of the pair in rig.json (default 0,1)")
    p.add_argument("--alpha", default=0.0, type=_unit_float,
                   help="0: only valid pixels (default), 1: every source pixel kept (as cv2.stereoRectify)")

    p = sub.add_parser("undistort", help="undistort images with a calibration: pinhole views centred on the optical "
                       "axis, framed within the lens's valid field (every model, fisheye included)",
                       epilog=_EXIT_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    common(p, board=False)
    p.add_argument("--calibration", required=True, metavar="JSON", help="calib.json written by calibrate (or a "
                   "rig.json with --camera)")
    p.add_argument("--camera", metavar="NAME", help="the camera of a rig.json written by calibrate-rig (its name or "
                   "index) whose calibration undistorts the images")
    p.add_argument("--out-dir", required=True, metavar="DIR", help="where to write the images (created)")
    framing = p.add_mutually_exclusive_group()
    framing.add_argument("--balance", default=0.0, type=_unit_float, metavar="B",
                         help="0 (default): the largest view without black borders; 1: the whole valid field "
                              "visible (black corners); between: linear in the focal length. The valid field is "
                              "where the lens model is monotonic and the calibration's corners reached")
    framing.add_argument("--fov", type=_view_angle, metavar="DEG",
                         help="horizontal field of view of the output in degrees instead of --balance (clamped to "
                              "the valid field, with a warning)")

    p = sub.add_parser("calibrate-many", help="calibrate many cameras (one directory of images each) with "
                       "Lightning's Trainer.predict; one JSON line per camera")
    p.add_argument("sets", nargs="+", metavar="SETS",
                   help="directories of images (one camera each), parents of such directories, videos (one camera "
                        "each), or globs")
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--board", type=_board_arg, metavar="COLSxROWS",
                       help="inner corners, e.g. 9x6 (or --charuco, --aprilgrid)")
    p.add_argument("--square", default=1.0, type=_length_arg, help="square side in world units (default 1)")
    charuco_options(p, which)
    p.add_argument("--output", required=True, metavar="JSONL",
                   help="JSON Lines file: one calibration per set (appended to; a JSON file of another kind is refused)")
    p.add_argument("--model", default="auto", choices=MODELS,
                   help="camera model (default auto: chosen per set by cross-validation; see calibrate --help)")
    p.add_argument("--detector", default=DEFAULT_DETECTOR, choices=("learned", "opencv"))
    p.add_argument("--device", default="cpu", type=_device_arg, help="cpu, cuda or cuda:N (default: cpu)")
    p.add_argument("--accelerator", default=None, choices=("auto", "cpu", "gpu"),
                   help="Lightning's accelerator for the processes (default: from --device)")
    p.add_argument("--devices", default=None, type=_positive_int, metavar="N",
                   help="processes per node, one per GPU with --accelerator gpu; each takes its own share of the sets "
                        "(default 1; see docs/fleet.md)")
    p.add_argument("--num-nodes", default=1, type=_positive_int, metavar="M",
                   help="nodes, started by SLURM's srun or by torchrun (default 1)")
    p.add_argument("--strategy", default="auto", choices=("auto", "ddp"),
                   help="Lightning's strategy: auto (DDP when --devices x --num-nodes > 1) or ddp")
    p.add_argument("--no-ransac", dest="use_ransac", action="store_false", help="keep every detected view")
    p.add_argument("--seed", default=0, type=int, help="RANSAC seed (default 0)")
    p.add_argument("--unweighted", dest="weigh_corners", action="store_false",
                   help="count every corner equally (the plain least-squares fit, as cv2.calibrateCamera: the lowest "
                        "RMS; by default corners are weighted by the precision measured on their image, which gives "
                        "more accurate cameras and a slightly higher RMS)")
    p.add_argument("--diagnostics", action="store_true",
                   help="also compute each set's quality figures and verdict (a few more solves per set)")
    p.add_argument("--sets-per-batch", default=4, type=_positive_int, metavar="N",
                   help="sets per predict step; sets of one image size are solved in one batched call (default 4)")
    p.add_argument("--workers", default=0, type=int, metavar="N", help="DataLoader workers loading sets (default 0)")
    p.add_argument("--batch-size", default=16, type=_positive_int, metavar="N",
                   help="images handed to the detector at once (default 16)")
    p.add_argument("--max-detection-side", default=2048, type=_detection_side, metavar="PX",
                   help="detect larger images on a downscaled copy (default 2048; 0 = off)")
    p.add_argument("--no-distortion-correction", dest="distortion_correction", action="store_false",
                   help="do not run the distortion-correction network")
    p.add_argument("--overwrite", action="store_true",
                   help="start the output file again (default: append, skipping sets already in it)")
    video_options(p, selection=False)

    p = sub.add_parser("demo", help="render a synthetic set with a known camera, calibrate it, compare")
    p.add_argument("--out-dir", default="ccs_demo", metavar="DIR", help="where to write images and results (default ./ccs_demo)")
    p.add_argument("--views", default=15, type=_positive_int, help="number of views (default %(default)s)")
    p.add_argument("--detector", default=DEFAULT_DETECTOR, choices=("learned", "opencv"))
    p.add_argument("--device", default="cpu", type=_device_arg)
    p.add_argument("--seed", default=0, type=int, help="seed of the rendered poses (default 0)")
    p.add_argument("--no-distortion-correction", dest="distortion_correction", action="store_false",
                   help="calibrate without the distortion-correction network")

    sub.add_parser("bench", help="benchmarks against OpenCV and other peers (see --help)", add_help=False)
    for name in LIGHTNING_COMMANDS:  # listed for --help; main() forwards them before parsing
        sub.add_parser(name, help=f"LightningCLI {name} (training; --config lightning_configs/<x>.yaml)", add_help=False)
    return parser


# ----------------------------------------------------------------------------------------------
# entry point
# ----------------------------------------------------------------------------------------------


def _run_lightning(argv: list[str]) -> int:
    try:  # Lightning is optional: without it the training commands say so in one line
        from ccs_kornia.training.cli import main as lightning_main
    except Exception as err:  # ImportError, or a broken optional dependency
        print(
            f"{PROG} {argv[0]}: error: the training command line is not available "
            f"(ccs_kornia.training.cli: {type(err).__name__}: {err})",
            file=sys.stderr,
        )
        return EXIT_USAGE
    result = lightning_main(argv)
    return int(result or 0)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status (:data:`EXIT_CODES`: 0 ok, 1 internal error, 2 usage or input
    error, 3 no result, 130 interrupted).

    Args:
        argv: arguments without the program name (default ``sys.argv[1:]``).
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    for stream in (sys.stdout, sys.stderr):  # a file name that is not UTF-8 is printed escaped, never a crash
        if getattr(stream, "errors", None) == "strict" and hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="backslashreplace")
    keep_freed_memory()  # this process is ours: freed tensors' memory is reused instead of mapped afresh
    if argv and argv[0] in LIGHTNING_COMMANDS:
        return _run_lightning(argv)
    if argv and argv[0] == "bench":
        # the bench's entry point loads its own modules: imported for ``bench`` only, not at every start-up
        from ccs_kornia.bench.__main__ import main as bench_main

        return bench_main(argv[1:], prog=f"{PROG} bench")
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_:
        return int(exit_.code or 0) if not isinstance(exit_.code, str) else EXIT_USAGE
    command = args.command
    try:
        # a command's module loads torch, OpenCV and the stages: imported once the command runs, never for --help
        # (docs/measurements.md)
        from ccs_kornia.commands._boards import resolve_board
        from ccs_kornia.commands._models import resolve_model

        module = importlib.import_module(f"ccs_kornia.commands.{command.replace('-', '_')}")
        resolve_board(args)
        resolve_model(args)
        return int(module.run(args) or 0)
    except UserError as err:
        print(f"{PROG} {command}: error: {err}", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt:
        print(f"{PROG} {command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as err:
        if os.environ.get("CCS_DEBUG", "") not in ("", "0"):
            raise
        message = str(err).strip().splitlines()[0] if str(err).strip() else ""
        print(
            f"{PROG} {command}: internal error: {type(err).__name__}: {message} "
            "(run with CCS_DEBUG=1 for the traceback)",
            file=sys.stderr,
        )
        return EXIT_INTERNAL


def run() -> NoReturn:
    """The command-line program (``python -m ccs_kornia``, ``ccs-kornia``): :func:`main`, then the process ends
    without the interpreter's teardown.

    Once the command is done, threads that are not daemons are waited for, the exit handlers run (``atexit``: worker
    processes, temporary folders, logging) and the standard streams are flushed; what is skipped is the interpreter's
    own teardown, whose garbage collections walk torch's whole object graph after every command
    (``docs/measurements.md``). Every file the package writes is closed by then.
    """
    code = main()
    # what the interpreter's exit does before its teardown: wait for the threads that are not daemons, then run the
    # exit handlers
    for thread in threading.enumerate():
        if thread is not threading.main_thread() and not thread.daemon:
            thread.join()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe (``| head``) or stream: nothing more can be said there
            pass
    os._exit(int(code or 0))


if __name__ == "__main__":  # pragma: no cover
    run()
