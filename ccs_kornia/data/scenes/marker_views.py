r"""Rendered views of marker boards (ChArUco, AprilGrid) with exact ids and corners.

A board's printed image (``board.texture()``: the image and the affine map from object points to its pixels) is
seen by a pinhole camera with OpenCV's lens distortion: every output pixel is traced back through the lens
(``cv2.undistortPoints``) to the board plane and sampled there on a supersampled grid, then area-averaged, so the
corners' true positions are ``cv2.projectPoints`` of the board's object points. Conditions (:data:`CONDITIONS`):
the board whole in the frame, cut by the frame (partial), low light (low contrast, sensor noise), blur, a
white-on-black print, a board seen from its back (the image mirrored), strong blur (defocus), small markers (the board
far away) and sensor noise.

Example:
    >>> import numpy as np
    >>> from ccs_kornia.modules.detection.boards import CharucoBoard
    >>> board = CharucoBoard(5, 7, 0.04, 0.02)
    >>> rng = np.random.default_rng(0)
    >>> img, truth = render_marker_view(board, *random_board_pose(board, rng), size=(320, 240), supersample=1)
    >>> img.shape, img.dtype, truth.shape
    ((240, 320), dtype('uint8'), (24, 2))
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

__all__ = ["CONDITIONS", "DIST", "FAR_CENTRE", "FAR_SPAN", "K", "NEAR_CENTRE", "NEAR_SPAN", "random_board_pose",
           "render_condition", "render_marker_view"]

#: the camera of the views (640 x 480 px) and its lens (strong barrel distortion, as a wide-angle lens)
K = np.array([[520.0, 0.0, 318.0], [0.0, 520.0, 242.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.28, 0.09, 0.0, 0.0, 0.0])
#: the rendering conditions of :func:`render_condition`
CONDITIONS = ("clean", "partial", "low light", "blur", "inverted", "mirrored", "strong blur", "small", "noise")
#: the board's width in the image (fraction of the image width): near (every condition but ``"small"``) and far
NEAR_SPAN = (0.45, 0.85)
FAR_SPAN = (0.2, 0.3)
#: where a whole board's centre lies (fraction of the image's width and height): near, and far (all over the image)
NEAR_CENTRE = (0.35, 0.65)
FAR_CENTRE = (0.2, 0.8)


@functools.lru_cache(maxsize=4)
def _rays(k: bytes, dist: bytes, w: int, h: int, f: int) -> np.ndarray:
    """The camera rays ``(x, y)`` (``z = 1``) of the supersampled pixels, ``(N, 1, 2)`` float32 (the same for every
    view of a camera)."""
    ys, xs = np.mgrid[0:h * f, 0:w * f].astype(np.float64)
    pix = np.stack([(xs + 0.5) / f - 0.5, (ys + 0.5) / f - 0.5], -1).reshape(-1, 1, 2)
    rays = cv2.undistortPoints(pix, np.frombuffer(k).reshape(3, 3), np.frombuffer(dist),
                               criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10))
    return rays.astype(np.float32)


@functools.lru_cache(maxsize=8)
def _texture(board, resolution: int | None, legacy: bool | None) -> tuple[np.ndarray, np.ndarray]:
    """The board's printed image and map (boards are frozen dataclasses: the same board prints the same)."""
    return board.texture(legacy=legacy) if resolution is None else board.texture(resolution, legacy=legacy)


def _extent(board) -> tuple[np.ndarray, np.ndarray]:
    pts = board.object_points().numpy()[:, :2]
    return pts.min(0), pts.max(0)


def random_board_pose(board, rng: np.random.Generator, partial: bool = False, k: np.ndarray = K,
                      size: tuple[int, int] = (640, 480), tilt_deg: float = 40.0,
                      span: tuple[float, float] = NEAR_SPAN, centre_range: tuple[float, float] = NEAR_CENTRE
                      ) -> tuple[np.ndarray, np.ndarray]:
    """A random ``(rvec, tvec)`` showing ``board`` to the camera ``k``: its corners' bounding box spans a fraction
    ``span`` of the image width (45 to 85 % by default), tilted up to ``tilt_deg``; whole in the frame (its centre
    within ``centre_range`` of the image's width and height), or
    (``partial``) with its centre near a side or corner of the frame so that the frame cuts it (about a fifth to a
    half of it outside)."""
    w, h = size
    lo, hi = _extent(board)
    centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, 0.0])
    extent = float(max(hi - lo))
    # the printed face towards the camera: a board whose y axis points up on the print (an AprilGrid: its texture
    # map flips y) is turned half a turn about its x axis
    face = np.diag([1.0, -1.0, -1.0]) if np.linalg.det(_texture(board, None, None)[1][:, :2]) < 0 else np.eye(3)
    for _ in range(200):
        axis = rng.normal(size=3)
        axis[2] *= 0.5
        angle = np.deg2rad(rng.uniform(0.0, tilt_deg))
        rvec = axis / np.linalg.norm(axis) * angle
        z = k[0, 0] * extent / (rng.uniform(*span) * w)
        if partial:
            side = rng.integers(0, 4)
            u = [rng.uniform(0.0, 0.12) * w, w - rng.uniform(0.0, 0.12) * w, rng.uniform(0.2, 0.8) * w,
                 rng.uniform(0.2, 0.8) * w][side]
            v = [rng.uniform(0.2, 0.8) * h, rng.uniform(0.2, 0.8) * h, rng.uniform(0.0, 0.12) * h,
                 h - rng.uniform(0.0, 0.12) * h][side]
        else:
            u, v = rng.uniform(*centre_range) * w, rng.uniform(*centre_range) * h
        rot = cv2.Rodrigues(rvec)[0] @ face
        rvec = cv2.Rodrigues(rot)[0].reshape(3)
        ray = np.linalg.solve(k, np.array([u, v, 1.0]))
        tvec = z * ray - rot @ centre
        corners = board.object_points().numpy()
        cam = corners @ rot.T + tvec
        if (cam[:, 2] <= 0.05 * z).any():
            continue
        proj = cam[:, :2] / cam[:, 2:] * k[0, 0] + k[:2, 2]
        inside = ((proj[:, 0] >= 0) & (proj[:, 0] <= w - 1) & (proj[:, 1] >= 0) & (proj[:, 1] <= h - 1)).mean()
        if (partial and 0.45 <= inside <= 0.85) or (not partial and inside == 1.0 and
                                                      (proj.min(0) > 0.08 * np.array([w, h])).all() and
                                                      (proj.max(0) < 0.92 * np.array([w, h])).all()):
            return rvec, tvec
    raise RuntimeError("no pose found for the board; is it much wider than tall?")


def render_marker_view(board, rvec: np.ndarray, tvec: np.ndarray, k: np.ndarray = K, dist: np.ndarray = DIST,
                       size: tuple[int, int] = (640, 480), supersample: int = 3, resolution: int | None = None,
                       legacy: bool | None = None, background: int = 160) -> tuple[np.ndarray, np.ndarray]:
    """A ``uint8`` view of ``board`` (anything with ``texture()`` and ``object_points()``: a ChArUco board, an
    AprilGrid) and its true corners ``(N, 2)`` px in corner-id order (NaN outside the image).

    ``resolution``: the texture's pixels per square (ChArUco) or per tag bit (AprilGrid); ``None``: the board's
    default. ``legacy``: a ChArUco board's layout to print.
    """
    w, h = size
    art, a = _texture(board, resolution, legacy)
    f = int(supersample)
    rays = _rays(np.asarray(k, dtype=np.float64).tobytes(), np.asarray(dist, dtype=np.float64).tobytes(), w, h, f)
    rot, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))
    # the plane z = 0 seen through the pinhole: (x, y, 1) ~ [r1 r2 t] (X, Y, 1); its inverse then the print's map
    plane = np.linalg.inv(np.stack([rot[:, 0], rot[:, 1], np.asarray(tvec, dtype=np.float64)], -1))
    total = np.vstack([a, [0.0, 0.0, 1.0]]) @ plane
    map_xy = cv2.perspectiveTransform(rays, total).reshape(h * f, w * f, 2)
    front = (rays.reshape(-1, 2) @ plane[2, :2].astype(np.float32) + np.float32(plane[2, 2])).reshape(h * f, w * f)
    # (X, Y, 1) = plane (x, y, 1) / depth: rays that meet the plane behind the camera are background
    map_xy[front <= 0] = -1e6
    big = cv2.remap(art, map_xy[..., 0], map_xy[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                    borderValue=background)
    image = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA) if f > 1 else big
    truth, _ = cv2.projectPoints(board.object_points().numpy(), np.asarray(rvec, dtype=np.float64),
                                 np.asarray(tvec, dtype=np.float64), k, dist)
    truth = truth.reshape(-1, 2)
    outside = (truth[:, 0] < 0) | (truth[:, 0] > w - 1) | (truth[:, 1] < 0) | (truth[:, 1] > h - 1)
    truth[outside] = np.nan
    return image, truth


def render_condition(board, condition: str, rng: np.random.Generator, k: np.ndarray = K, dist: np.ndarray = DIST,
                     size: tuple[int, int] = (640, 480), supersample: int = 3, legacy: bool | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """A random view of ``board`` under ``condition`` (:data:`CONDITIONS`) and its true corners (NaN outside the
    image; mirrored views: the corners' positions on the flipped image).

    ``"low light"``: the print's black and white squeezed to about 10 and 55 grey levels with sensor noise (sigma
    2.5); ``"blur"``: a Gaussian of sigma 0.8 to 1.6 px (defocus); ``"inverted"``: a white-on-black print;
    ``"mirrored"``: the image flipped left-right (the board seen from its back through a transparent print);
    ``"strong blur"``: a Gaussian of sigma 1.8 to 3 px; ``"small"``: the board spans :data:`FAR_SPAN` of the image
    width (far away: its markers' bits are one to two pixels), anywhere in the image (:data:`FAR_CENTRE`);
    ``"noise"``: sensor noise of sigma 10 to 16 grey levels.
    Every condition but ``"partial"`` shows the board whole.

    Example:
        >>> from ccs_kornia.modules.detection.boards import CharucoBoard
        >>> img, truth = render_condition(CharucoBoard(5, 7, 0.04, 0.02), "small", np.random.default_rng(0),
        ...                               size=(320, 240), supersample=1)
        >>> img.shape, bool(np.isfinite(truth).all())
        ((240, 320), True)
    """
    if condition not in CONDITIONS:
        raise ValueError(f"unknown condition {condition!r}; expected one of {', '.join(CONDITIONS)}")
    far = condition == "small"
    rvec, tvec = random_board_pose(board, rng, partial=condition == "partial", k=k, size=size,
                                   span=FAR_SPAN if far else NEAR_SPAN, centre_range=FAR_CENTRE if far else NEAR_CENTRE)
    image, truth = render_marker_view(board, rvec, tvec, k, dist, size, supersample, legacy=legacy)
    img = image.astype(np.float64)
    if condition == "low light":
        lo, hi = rng.uniform(6, 14), rng.uniform(45, 65)
        img = lo + img / 255.0 * (hi - lo) + rng.normal(0.0, 2.5, img.shape)
    elif condition == "blur":
        img = cv2.GaussianBlur(img, (0, 0), rng.uniform(0.8, 1.6))
    elif condition == "strong blur":
        img = cv2.GaussianBlur(img, (0, 0), rng.uniform(1.8, 3.0))
    elif condition == "noise":
        img = img + rng.normal(0.0, rng.uniform(10.0, 16.0), img.shape)
    elif condition == "inverted":
        img = 255.0 - img
    image = np.clip(np.round(img), 0, 255).astype(np.uint8)
    if condition == "mirrored":
        image = np.ascontiguousarray(image[:, ::-1])
        truth = truth.copy()
        truth[:, 0] = size[0] - 1 - truth[:, 0]
    return image, truth
