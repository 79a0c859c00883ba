"""Self-labels of real photographs: the corners this package finds with confidence on clean views of real boards.

A corner is a label when this package's detector finds it on the clean photograph (the learned chessboard detector's
whole board; the ChArUco detector's corners, both paths merged) **and** OpenCV places a corner within
:data:`AGREE_PX` of it (``cv2.findChessboardCornersSB``; ``cv2.aruco.CharucoDetector`` on the print's variants:
inverted, mirrored). A view with a corner of ours that OpenCV does not confirm is left out whole, so no true corner of a
kept view is missing from its labels (a missing one would teach the network that a corner is background). The labels
file feeds :class:`~ccs_kornia.data.datamodules.real_pairs_datamodule.RealPairsDataModule`, which makes degraded
copies of the views with these labels as targets (self-training, ``lightning_configs/detector_selftrain.yaml``).

Command::

    python -m ccs_kornia.training.self_labels runs/selftrain/labels.json --real-dir ../shared/data/real

(the sets of :data:`~ccs_kornia.data.datamodules.real_pairs_datamodule.SELF_TRAINING_SETS` unless ``--sets`` names
others).
"""

from __future__ import annotations

import argparse
import glob
import json
from pathlib import Path

import cv2
import numpy as np
import torch

from ccs_kornia.data.datamodules.real_pairs_datamodule import SELF_TRAINING_SETS

__all__ = ["AGREE_PX", "make_self_labels", "view_labels"]

#: our corner and OpenCV's agree within this distance (px) on the clean photograph
AGREE_PX = 1.0
_IMAGES = ("*.jpg", "*.jpeg", "*.png", "*.bmp", "*.JPG", "*.PNG")


def _confirmed(ours: np.ndarray, theirs: np.ndarray) -> np.ndarray:
    """``(N,)`` bool: each of ``ours`` ``(N, 2)`` has one of ``theirs`` ``(M, 2)`` within :data:`AGREE_PX`."""
    if len(theirs) == 0:
        return np.zeros(len(ours), bool)
    return np.linalg.norm(ours[:, None] - theirs[None], axis=-1).min(1) <= AGREE_PX


def _square_px(corners: np.ndarray) -> float:
    """Median distance from each corner to its nearest neighbour (the square's side in px)."""
    d = np.linalg.norm(corners[:, None] - corners[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    return float(np.median(d.min(1)))


def view_labels(ours: np.ndarray, theirs: np.ndarray) -> np.ndarray | None:
    """The labels ``(N, 2)`` of one view: ``ours`` when OpenCV's ``theirs`` confirms every one, else ``None``.

    Example:
        >>> ours = np.array([[10.0, 10.0], [20.0, 10.0], [10.0, 20.0], [20.0, 20.0]])
        >>> view_labels(ours, ours + 0.3).shape, view_labels(ours, ours[:3]) is None
        ((4, 2), True)
    """
    ours = ours[np.isfinite(ours).all(-1)]
    if len(ours) < 4 or not _confirmed(ours, theirs[np.isfinite(theirs).all(-1)]).all():
        return None
    return ours


def _chessboard_views(files: list[str], board: tuple[int, int]) -> list[np.ndarray | None]:
    from ccs_kornia.modules.detection.factory import make_detector

    det = make_detector("learned")
    flags = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    out = []
    for f in files:
        image = cv2.imread(f, cv2.IMREAD_GRAYSCALE)
        with torch.inference_mode():
            res = det(torch.from_numpy(image).float()[None, None] / 255.0, board)
        ok, theirs = cv2.findChessboardCornersSB(image, board, flags=flags)
        if not bool(res.found[0]) or not ok:
            out.append(None)
            continue
        out.append(view_labels(res.corners[0].double().numpy(), theirs.reshape(-1, 2).astype(np.float64)))
    return out


def _charuco_views(files: list[str], board) -> list[np.ndarray | None]:
    from ccs_kornia.modules.detection.markers.charuco import charuco_paths
    from ccs_kornia.modules.detection.markers.corner_merge import MarkerPaths

    detector = cv2.aruco.CharucoDetector(board.cv2_board(False))
    out = []
    for f in files:
        image = cv2.imread(f, cv2.IMREAD_GRAYSCALE)
        x = torch.from_numpy(image).float()[None, None] / 255.0
        res = charuco_paths(x, board, min_corners=1, num_workers=1, paths=(MarkerPaths.BOTH,))[MarkerPaths.BOTH]
        theirs = []
        for inverted in (False, True):  # a white-on-black print, a board seen from behind (mirrored)
            for mirrored in (False, True):
                src = 255 - image if inverted else image
                src = cv2.flip(src, 1) if mirrored else src
                corners, ids, _, _ = detector.detectBoard(src)
                if ids is not None and len(ids):
                    pts = corners.reshape(-1, 2).astype(np.float64)
                    if mirrored:
                        pts[:, 0] = image.shape[1] - 1 - pts[:, 0]
                    theirs.append(pts)
        if not bool(res.found[0]) or not theirs:
            out.append(None)
            continue
        ours = res.corners[0].double().numpy()[res.valid[0].numpy()]
        out.append(view_labels(ours, np.concatenate(theirs)))
    return out


def make_self_labels(real_dir: str | Path, sets: dict | None = None, log=print) -> dict:
    """The labels of every image of ``sets`` (``{name: (kind, board, file patterns)}``, default
    :data:`~ccs_kornia.data.datamodules.real_pairs_datamodule.SELF_TRAINING_SETS`) under ``real_dir``.

    Returns:
        ``{"real_dir": str, "views": [{"set", "file" (relative to real_dir), "corners" [[x, y], ...],
        "square_px"}, ...], "left_out": {set: count}}``.
    """
    from ccs_kornia.modules.detection.boards import CharucoBoard

    root = Path(real_dir)
    sets = SELF_TRAINING_SETS if sets is None else sets
    views, left_out = [], {}
    for name, (kind, board, patterns) in sets.items():
        files = sorted({f for p in (patterns or _IMAGES) for f in glob.glob(str(root / name / p))})
        if kind == "chessboard":
            got = _chessboard_views(files, tuple(board))
        else:
            got = _charuco_views(files, CharucoBoard(*board))
        kept = 0
        for f, c in zip(files, got):
            if c is not None:
                views.append({"set": name, "file": str(Path(f).relative_to(root)), "corners": c.round(4).tolist(),
                              "square_px": round(_square_px(c), 3)})
                kept += 1
        left_out[name] = len(files) - kept
        log(f"[self_labels] {name}: {kept} of {len(files)} views labelled")
    return {"real_dir": str(root), "views": views, "left_out": left_out}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description="Self-labels of the real training sets (clean views, confirmed corners).")
    p.add_argument("out", help="labels file (JSON)")
    p.add_argument("--real-dir", default="../shared/data/real")
    p.add_argument("--sets", nargs="+", default=None, help=f"a subset of {list(SELF_TRAINING_SETS)}")
    args = p.parse_args(argv)
    sets = {k: SELF_TRAINING_SETS[k] for k in args.sets} if args.sets else None
    labels = make_self_labels(args.real_dir, sets)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(labels))


if __name__ == "__main__":
    main()
