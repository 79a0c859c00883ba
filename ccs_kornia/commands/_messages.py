"""What the commands say about a run's result, in words: why a board was found in no image or a camera could not be
calibrated, a board that looks larger than the one given, what ``--allow-weak`` let through, the verdict."""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

from ccs_kornia.modules.calibration.quality.degeneracy import WEAK_CHECKS
from ccs_kornia.modules.calibration.quality.diagnostics import HALVES_DISAGREE

__all__ = ["board_size_hint", "failure_message", "files_note", "not_found_message", "verdict_line", "weak_lines"]


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
    "circles": "check --circles COLSxROWS (the dots, as OpenCV's findCirclesGrid counts them), --asymmetric and "
               "--marked-origin",
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


def failure_message(data: dict[str, Any], board: tuple[int, int], readable: int) -> str:
    """Why a camera's record (:func:`~ccs_kornia.outputs.records.camera_record`, ``success`` false) holds no calibration, in
    one line: board never found, too few usable views, the solver's refusals with the views they name."""
    files = data["num_views"]["files"]
    if data["num_views"]["found"] == 0:
        return not_found_message(board, readable, files, str(data.get("detector", "")))
    if data["num_views"]["usable"] < 3:
        return (f"only {data['num_views']['usable']} usable view(s) of the {board[0]}x{board[1]} board among "
                f"{files} files (board found in {data['num_views']['found']}); at least 3 are needed")
    if data.get("errors"):  # the solver's refusals (degeneracy checks) name the problem and the views

        weak = all(i.get("check") in WEAK_CHECKS and i.get("value") is not None for i in data["errors"])
        return (f"calibration refused on {data['num_views']['usable']} views: "
                + "; ".join(i["message"] + files_note(i) for i in data["errors"])
                + ("; --allow-weak calibrates anyway (verdict not reliable)" if weak else ""))
    why = data["error"] if data["error"].startswith("calibration failed") else \
        f"calibration failed on {data['num_views']['usable']} views: {data['error']}"
    return (f"{why}; the views may be degenerate (e.g. all fronto-parallel, or copies of one view) or "
            "inconsistent: add views with the board tilted in different directions")


def files_note(issue: dict[str, Any], most: int = 6) -> str:
    """`` (files: a.jpg, b.jpg, ...)`` for the views a degeneracy check names."""
    names = [os.path.basename(f) for f in issue.get("files", [])]
    if not names:
        return ""
    more = f", ... ({len(names)} in all)" if len(names) > most else ""
    return f" (files: {', '.join(names[:most])}{more})"


def verdict_line(quality: dict[str, Any] | None) -> str:
    """``verdict: ... (held-out views ... px, ...)`` from the diagnostics (empty without them), and what the split
    halves say where the verdict's reasons name them."""
    if not quality:
        return ""
    figures = [f"{label} {quality[key]:.3f} px" for label, key in (
        ("held-out views", "heldout_rms_px"), ("halves differ where the boards were by", "cv_covered_rms_px"),
        ("uncertainty at the centre", "uncertainty_centre_px")) if quality.get(key) is not None]
    halves = [r for r in quality.get("reasons") or [] if HALVES_DISAGREE in r and r not in quality["verdict"]]
    return (f"verdict: {quality['verdict']}" + (f" ({', '.join(figures)})" if figures else "")
            + "".join(f"; {r}" for r in halves))
