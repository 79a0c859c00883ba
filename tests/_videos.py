"""Small board recordings for the video tests: rendered views of a known camera written as video files."""

from __future__ import annotations

import cv2
import numpy as np
import torch

K_VIDEO = torch.tensor([[300.0, 0.0, 159.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]])
BOARD = (6, 4)
SQUARE = 0.025
SIZE = (320, 240)

#: (fourcc, extension) OpenCV's FFmpeg writes here: MPEG-4 part 2 in mp4, Motion JPEG in avi
FORMATS = (("mp4v", ".mp4"), ("MJPG", ".avi"))


def write_video(path: str, frames, fps: float = 10.0, fourcc: str = "MJPG") -> str:
    """Grey frames ``(V, 1, H, W)`` float in [0, 1] (or ``(V, H, W)`` uint8) written as a colour video."""
    frames = frames if isinstance(frames, np.ndarray) else (frames[:, 0].clamp(0, 1) * 255).round().byte().numpy()
    h, w = frames.shape[1:3]
    out = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*fourcc), fps, (w, h))
    assert out.isOpened(), f"OpenCV cannot write {fourcc} to {path}"
    for frame in frames:
        out.write(cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR))
    out.release()
    return path


def board_frames(num_views: int, seed: int = 0, blank: tuple[int, ...] = ()) -> np.ndarray:
    """``num_views`` rendered views (uint8, ``(V, H, W)``) of a 6x4 board; the views listed in ``blank`` show no
    board (the background alone)."""
    from ccs_kornia.data.scenes import make_calibration_set

    views = make_calibration_set(K_VIDEO, BOARD, SQUARE, SIZE, num_views=num_views, seed=seed, supersample=2)
    frames = (views.images[:, 0].clamp(0, 1) * 255).round().byte().numpy()
    for k in blank:
        frames[k] = 128
    return frames


def board_video(path: str, num_views: int = 12, seed: int = 0, fps: float = 10.0, fourcc: str = "MJPG",
                blank: tuple[int, ...] = ()) -> str:
    """A recording of ``num_views`` board views (:func:`board_frames`)."""
    return write_video(path, board_frames(num_views, seed, blank), fps, fourcc)
