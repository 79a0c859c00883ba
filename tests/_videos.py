"""Small board recordings for the video tests: a chessboard seen by a known pinhole camera along a path of poses,
written as video files (OpenCV's FFmpeg writer: MPEG-4 part 2 in mp4, Motion JPEG in avi).

The board is a homography of a printed texture (warped at twice the size, then averaged down), fast enough to make
a few dozen frames per test.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

K_VIDEO = np.array([[300.0, 0.0, 159.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]])
BOARD = (6, 4)
SQUARE = 0.025
SIZE = (320, 240)

#: (fourcc, extension) OpenCV's FFmpeg writes here
FORMATS = (("mp4v", ".mp4"), ("MJPG", ".avi"))

_PX = 40  # texture pixels per square


def _texture() -> tuple[np.ndarray, np.ndarray]:
    """The printed board (a one-square white margin) and the map from board metres to texture pixels."""
    cols, rows = BOARD
    sq = np.indices((rows + 1, cols + 1)).sum(0) % 2
    board = np.kron(sq * 255, np.ones((_PX, _PX))).astype(np.uint8)
    board = cv2.copyMakeBorder(board, _PX, _PX, _PX, _PX, cv2.BORDER_CONSTANT, value=255)
    s = _PX / SQUARE  # the first inner corner (SQUARE, SQUARE) at texture pixel 2 * _PX - 0.5
    to_texture = np.array([[s, 0.0, _PX - 0.5], [0.0, s, _PX - 0.5], [0.0, 0.0, 1.0]])
    return board, to_texture


def pose(k: int, num: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation (board -> camera) of frame ``k`` of ``num``: a slow sweep of tilts and positions."""
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 2 * math.pi, 5)
    u = k / max(1, num)
    rx = 0.55 * math.sin(2 * math.pi * u + phase[0])
    ry = 0.55 * math.sin(4 * math.pi * u + phase[1])
    rz = 0.3 * math.sin(2 * math.pi * u + phase[2])
    R, _ = cv2.Rodrigues(np.array([rx, ry, rz]))
    centre = np.array([(BOARD[0] + 1) * SQUARE / 2, (BOARD[1] + 1) * SQUARE / 2, 0.0])
    target = np.array([0.03 * math.sin(2 * math.pi * u + phase[3]), 0.02 * math.sin(2 * math.pi * u + phase[4]),
                       0.28 + 0.04 * math.cos(2 * math.pi * u)])
    return R, target - R @ centre


def board_frames(num: int, seed: int = 0, blank: tuple[int, ...] = (), shift=(0.0, 0.0, 0.0)) -> np.ndarray:
    """``num`` grey ``uint8`` frames ``(V, H, W)`` of the board along :func:`pose`; frames in ``blank`` show only
    the background; ``shift``: the camera's frame moved by ``x_cam = x + shift`` (a rig's second camera)."""
    poses = [None if k in blank else pose(k, num, seed) for k in range(num)]
    return posed_frames([None if p is None else (p[0], p[1] + np.asarray(shift, dtype=float)) for p in poses], seed)


def posed_frames(poses, seed: int = 0) -> np.ndarray:
    """Grey ``uint8`` frames ``(V, H, W)`` of the board at ``poses`` (``(R, t)`` board -> camera each; ``None``: only
    the background)."""
    texture, to_texture = _texture()
    rng = np.random.default_rng(1000 + seed)
    w, h = SIZE
    background = cv2.GaussianBlur(rng.uniform(70, 180, (2 * h, 2 * w)).astype(np.float32), (0, 0), 6)
    up = np.diag([2.0, 2.0, 1.0]) @ np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1]])  # pixel centres at integers
    frames = np.empty((len(poses), h, w), np.uint8)
    for k, board_pose in enumerate(poses):
        if board_pose is None:
            frames[k] = cv2.resize(background, (w, h), interpolation=cv2.INTER_AREA).astype(np.uint8)
            continue
        R, t = board_pose
        H = up @ K_VIDEO @ np.column_stack([R[:, 0], R[:, 1], t]) @ np.linalg.inv(to_texture)
        warped = cv2.warpPerspective(texture.astype(np.float32), H, (2 * w, 2 * h), flags=cv2.INTER_LINEAR,
                                     borderValue=-1.0)
        image = np.where(warped >= 0, warped, background)
        frames[k] = np.clip(cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA), 0, 255).round().astype(np.uint8)
    return frames


def tilted_pose(rx: float, ry: float, shift=(0.0, 0.0), distance: float = 0.28) -> tuple[np.ndarray, np.ndarray]:
    """The board's centre ``distance`` m ahead (moved by ``shift`` m across), tilted by ``rx``, ``ry`` rad."""
    R, _ = cv2.Rodrigues(np.array([rx, ry, 0.0]))
    centre = np.array([(BOARD[0] + 1) * SQUARE / 2, (BOARD[1] + 1) * SQUARE / 2, 0.0])
    return R, np.array([shift[0], shift[1], distance]) - R @ centre


def write_video(path: str, frames: np.ndarray, fps: float = 10.0, fourcc: str = "MJPG") -> str:
    """Grey ``uint8`` frames ``(V, H, W)`` written as a colour video."""
    h, w = frames.shape[1:3]
    out = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*fourcc), fps, (w, h))
    assert out.isOpened(), f"OpenCV cannot write {fourcc} to {path}"
    for frame in frames:
        out.write(cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR))
    out.release()
    return path


def board_video(path: str, num: int = 16, seed: int = 0, fps: float = 10.0, fourcc: str = "MJPG",
                blank: tuple[int, ...] = (), shift=(0.0, 0.0, 0.0)) -> str:
    """A recording of ``num`` frames of the board (:func:`board_frames`)."""
    return write_video(path, board_frames(num, seed, blank, shift), fps, fourcc)


def truncated(path: str, out: str, keep: float = 0.5) -> str:
    """A copy of ``path`` cut after ``keep`` of its bytes."""
    with open(path, "rb") as handle:
        data = handle.read()
    with open(out, "wb") as handle:
        handle.write(data[: int(len(data) * keep)])
    return out
