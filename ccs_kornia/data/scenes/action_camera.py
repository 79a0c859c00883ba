r"""Rendered photographs of a large marker board by an action camera: what real photographs of it hold.

An action camera (1280 x 720 px, a wide lens with strong barrel distortion: OpenCV's k1 = -0.32, k2 = 0.09,
k3 = -0.006 at fx = 600 px: the frame's corners see 1.76 times as far from the axis as a pinhole would show them,
about 120 degrees across the diagonal, and a straight edge there bends as it does on a GoPro; the model is one to one
over the whole frame) sees a board that fills much of the frame
(its corners span 60 to 110 % of the image width), tilted up to 45 degrees and often cut by the frame. The board is
traced through the lens by :func:`~ccs_kornia.data.scenes.marker_views.render_marker_view` (supersampled), then given
what a real photograph adds:

* the print's black and white (black 15 to 45, white 165 to 235 grey levels) under uneven light (a linear gradient of
  up to +-25 % across the frame) and the lens's vignetting (20 to 45 % at the frame's corners);
* clutter around the board (:func:`~ccs_kornia.data.render.augment.textured_background`) beyond the print's white
  margin;
* the print's and the optics' softness (a Gaussian of sigma 0.5 to 1.0 px);
* a sensor's noise (read noise of 1 to 2 grey levels and shot noise of about 0.3 grey level per electron);
* the camera's JPEG (quality 70 to 92).

The true corners are ``cv2.projectPoints`` of the board's object points, kept where they lie in the image and within
the lens's field of view (a point beyond it would fold back into the image through the polynomial).

Example:
    >>> from ccs_kornia.modules.detection.boards import CharucoBoard
    >>> board = CharucoBoard(19, 10, 0.04, 0.03, "DICT_4X4_250")
    >>> img, truth = render_action_view(board, np.random.default_rng(0), supersample=1)
    >>> img.shape, img.dtype, truth.shape
    ((720, 1280), dtype('uint8'), (162, 2))
"""

from __future__ import annotations

import functools

import cv2
import numpy as np
import torch

from ccs_kornia.data.render.augment import textured_background, vignetting
from ccs_kornia.data.scenes.marker_views import render_marker_view

__all__ = ["ACTION_DIST", "ACTION_K", "ACTION_SIZE", "MIN_VISIBLE", "SPAN", "action_board_pose", "field_radius",
           "render_action_view"]

#: the action camera: image size ``(W, H)``, intrinsics and OpenCV's 5 coefficients (strong barrel distortion)
ACTION_SIZE = (1280, 720)
ACTION_K = np.array([[600.0, 0.0, 642.0], [0.0, 600.0, 358.0], [0.0, 0.0, 1.0]])
ACTION_DIST = np.array([-0.32, 0.09, 0.0004, -0.0003, -0.006])
#: the board's inner corners span this fraction of the image width (through a pinhole at the image centre)
SPAN = (0.6, 1.1)
#: a view shows at least this fraction of the board's corners
MIN_VISIBLE = 0.4


@functools.lru_cache(maxsize=4)
def _field_radius(k: bytes, dist: bytes, w: int, h: int) -> float:
    pix = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]]).reshape(-1, 1, 2)
    rays = cv2.undistortPoints(pix, np.frombuffer(k).reshape(3, 3), np.frombuffer(dist),
                               criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10))
    return float(np.linalg.norm(rays.reshape(-1, 2), axis=-1).max())


def field_radius(k: np.ndarray = ACTION_K, dist: np.ndarray = ACTION_DIST, size: tuple[int, int] = ACTION_SIZE
                 ) -> float:
    """The largest normalised radius ``|(x, y)|`` (``z = 1``) the image's pixels see through the lens: its field of
    view.

    Example:
        >>> 1.7 < field_radius() < 1.8
        True
    """
    k = np.asarray(k, dtype=np.float64)
    dist = np.asarray(dist, dtype=np.float64)
    return _field_radius(k.tobytes(), dist.tobytes(), int(size[0]), int(size[1]))


def _visible(board, rvec: np.ndarray, tvec: np.ndarray, k: np.ndarray, dist: np.ndarray,
             size: tuple[int, int]) -> np.ndarray:
    """The board's corners ``(N, 2)`` projected through the lens, NaN outside the image or the field of view."""
    obj = board.object_points().numpy()
    cam = obj @ cv2.Rodrigues(rvec)[0].T + tvec
    proj, _ = cv2.projectPoints(obj, rvec, tvec, k, dist)
    proj = proj.reshape(-1, 2)
    radius = np.linalg.norm(cam[:, :2] / np.maximum(cam[:, 2:], 1e-9), axis=-1)
    w, h = size
    ok = (cam[:, 2] > 0) & (radius <= field_radius(k, dist, size)) & (proj[:, 0] >= 0) & (proj[:, 0] <= w - 1) & \
        (proj[:, 1] >= 0) & (proj[:, 1] <= h - 1)
    proj[~ok] = np.nan
    return proj


def action_board_pose(board, rng: np.random.Generator, k: np.ndarray = ACTION_K, dist: np.ndarray = ACTION_DIST,
                      size: tuple[int, int] = ACTION_SIZE, span: tuple[float, float] = SPAN, tilt_deg: float = 45.0,
                      min_visible: float = MIN_VISIBLE) -> tuple[np.ndarray, np.ndarray]:
    """A random ``(rvec, tvec)`` of ``board`` (a ChArUco board: its printed face towards ``+z`` of its frame)
    filling much of the frame: its corners' extent spans a fraction ``span`` of the image width, its centre within
    the middle 40 % of the image, tilted up to ``tilt_deg`` about any axis (half as much about the optical axis's
    direction) and often cut by the frame; at least ``min_visible`` of its corners in the image.

    Example:
        >>> from ccs_kornia.modules.detection.boards import CharucoBoard
        >>> rvec, tvec = action_board_pose(CharucoBoard(19, 10, 0.04, 0.03, "DICT_4X4_250"), np.random.default_rng(0))
        >>> rvec.shape, tvec.shape, bool(tvec[2] > 0)
        ((3,), (3,), True)
    """
    w, h = size
    obj = board.object_points().numpy()
    lo, hi = obj[:, :2].min(0), obj[:, :2].max(0)
    centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, 0.0])
    extent = float(max(hi - lo))
    for _ in range(500):
        axis = rng.normal(size=3)
        axis[2] *= 0.5
        rvec = axis / np.linalg.norm(axis) * np.deg2rad(rng.uniform(0.0, tilt_deg))
        rot = cv2.Rodrigues(rvec)[0]
        z = k[0, 0] * extent / (rng.uniform(*span) * w)
        ray = np.linalg.solve(k, np.array([rng.uniform(0.3, 0.7) * w, rng.uniform(0.3, 0.7) * h, 1.0]))
        tvec = z * ray - rot @ centre
        if ((obj @ rot.T + tvec)[:, 2] <= 0.1 * z).any():
            continue
        if np.isfinite(_visible(board, rvec, tvec, k, dist, size)).all(-1).mean() >= min_visible:
            return rvec, tvec
    raise RuntimeError("no pose found for the board")


def render_action_view(board, rng: np.random.Generator, k: np.ndarray = ACTION_K, dist: np.ndarray = ACTION_DIST,
                       size: tuple[int, int] = ACTION_SIZE, supersample: int = 3, legacy: bool | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
    """A random photograph of ``board`` by the action camera (module doc) and its true corners ``(N, 2)`` px by
    id (NaN outside the image or the lens's field of view).

    Args:
        board: a ChArUco board (``texture()`` and ``object_points()``).
        rng: every draw of the view (the same generator state gives the same view).
        k, dist, size: the camera: ``(3, 3)``, OpenCV's 5 coefficients, ``(W, H)``.
        supersample: the board is traced on a grid this many times finer, then area-averaged.
        legacy: the ChArUco layout printed (``None``: the board's).

    Returns:
        ``(image, truth)``: ``(H, W)`` ``uint8`` grey and ``(N, 2)`` float64.
    """
    w, h = size
    rvec, tvec = action_board_pose(board, rng, k, dist, size)
    # the print on black and on white: where they differ is the background, by the fraction of each pixel
    on_black, _ = render_marker_view(board, rvec, tvec, k, dist, size, supersample, legacy=legacy, background=0)
    on_white, _ = render_marker_view(board, rvec, tvec, k, dist, size, supersample, legacy=legacy, background=255)
    outside = (on_white.astype(np.float64) - on_black) / 255.0
    black, white = rng.uniform(15.0, 45.0), rng.uniform(165.0, 235.0)
    gen = torch.Generator().manual_seed(int(rng.integers(0, 2**31 - 1)))
    clutter = textured_background(1, size, gen, dtype=torch.float64)[0, 0].numpy()
    clutter = rng.uniform(20.0, 60.0) + clutter * rng.uniform(80.0, 180.0)
    img = (1.0 - outside) * black + on_black * (white - black) / 255.0 + outside * clutter
    # uneven light: a gradient across the frame, then the lens's vignetting
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    g = rng.uniform(-0.25, 0.25, size=2)
    img = img * (1.0 + g[0] * (xs / (w - 1) - 0.5) * 2.0 + g[1] * (ys / (h - 1) - 0.5) * 2.0)
    img = vignetting(torch.from_numpy(img / 255.0)[None, None].clamp(0.0, 1.0), gen, strength=(0.2, 0.45),
                     power=(2.0, 3.0), centre_jitter=0.05)[0, 0].numpy() * 255.0
    img = cv2.GaussianBlur(img, (0, 0), rng.uniform(0.5, 1.0))
    electrons = 0.3
    img = rng.poisson(np.clip(img, 0.0, None) / electrons) * electrons + rng.normal(0.0, rng.uniform(1.0, 2.0),
                                                                                    img.shape)
    ok, buf = cv2.imencode(".jpg", np.clip(np.rint(img), 0, 255).astype(np.uint8),
                           [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(70, 93))])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE), _visible(board, rvec, tvec, k, dist, size)
