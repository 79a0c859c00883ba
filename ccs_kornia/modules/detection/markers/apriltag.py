r"""A single AprilTag as a calibration target: OpenCV decodes the tag, this package places its four corners.

Many robot set-ups carry one printed tag (ViSP's hand-eye tutorial, apriltag_ros): four corners, the outer corners of
its black square. :class:`AprilTagTarget` describes it as a 2x2 corner grid in the package's order (``n = row * 2 +
col``: top left, top right, bottom left, bottom right as the tag is printed), its origin at the tag's centre, ``x``
right, ``y`` down, ``z`` into the print (a chessboard's axes), so every solver takes it as a board.

:func:`detect_apriltag` on each image:

1. **tag**: ``cv2.aruco.ArucoDetector`` with OpenCV's dictionary of the family (``DICT_APRILTAG_36h11``, a one-bit
   black border) decodes the tags; the target's id (or, without one, the id found in most images) is kept;
2. **corners**: each side of the black square is measured on the image: along the side, at points a few tenths of
   a bit apart, the edge is located to a fraction of a pixel across it (the centroid of the intensity's derivative from
   black to white around its peak, within :data:`SEARCH_BITS` bits of the side: clear of the border's inner edge a bit
   further in); a line fitted to those edge points (weighted by their contrast), and
   the corners are where neighbouring lines meet. Two rounds, the second on the sides the first placed. With the
   camera's lens (``undistort`` / ``distort``), the edge points are straightened before the lines are fitted.

A corner moved more than :data:`MAX_SHIFT_BITS` bits from OpenCV's, or a side with too few edge points, leaves the
tag not found in that image (with the reason).

:class:`AprilTagDetector` is the same with the chessboard detectors' interface, the camera's lens given as the camera
itself: the calibration pipeline runs it on its sources, in its batches and worker processes.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.modules.detection.base import ChessboardDetector, DetectionResult
from ccs_kornia.modules.detection.boards import aruco_dictionary
from ccs_kornia.runtime.checks import check_grey_images

__all__ = ["APRILTAG_FAMILIES", "MAX_SHIFT_BITS", "SEARCH_BITS", "AprilTagDetector", "AprilTagTarget",
           "detect_apriltag", "refine_tag_corners"]

#: tag families by the name users give (``--apriltag 36h11``) -> OpenCV's dictionary and the bits across the black
#: square (data bits plus the one-bit border on each side)
APRILTAG_FAMILIES: dict[str, tuple[str, int]] = {
    "16h5": ("DICT_APRILTAG_16h5", 6),
    "25h9": ("DICT_APRILTAG_25h9", 7),
    "36h10": ("DICT_APRILTAG_36h10", 8),
    "36h11": ("DICT_APRILTAG_36h11", 8),
}
#: the edge is searched within this many bits of the side's current line (the border's inner edge is one bit in)
SEARCH_BITS = 0.4
#: a refined corner farther than this (bits) from OpenCV's is refused
MAX_SHIFT_BITS = 0.5


@dataclass(frozen=True)
class AprilTagTarget:
    """One AprilTag: its family, the black square's side (``size``, the world unit) and optionally its id.

    Example:
        >>> t = AprilTagTarget("36h11", 0.048)
        >>> t.board_size, t.object_points()[3].tolist()
        ((2, 2), [0.024, 0.024, 0.0])
    """

    family: str = "36h11"
    size: float = 1.0
    tag_id: int | None = None

    def __post_init__(self) -> None:
        if self.family not in APRILTAG_FAMILIES:
            raise ValueError(f"unknown AprilTag family {self.family!r}; expected one of {', '.join(APRILTAG_FAMILIES)}")
        if not (float(self.size) > 0):
            raise ValueError(f"the tag's size must be positive, got {self.size}")

    @property
    def board_size(self) -> tuple[int, int]:
        """The corner grid ``(2, 2)``."""
        return (2, 2)

    @property
    def dictionary(self) -> str:
        """OpenCV's dictionary name."""
        return APRILTAG_FAMILIES[self.family][0]

    @property
    def bits(self) -> int:
        """Bits across the black square (border included)."""
        return APRILTAG_FAMILIES[self.family][1]

    def object_points(self, dtype: torch.dtype = torch.float64) -> torch.Tensor:
        """The four corners :math:`(4, 3)` in grid order (module doc), centred on the tag."""
        h = float(self.size) / 2
        return torch.tensor([[-h, -h, 0.0], [h, -h, 0.0], [-h, h, 0.0], [h, h, 0.0]], dtype=dtype)

    def texture(self, pixels_per_bit: int = 24, legacy: bool | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The printed tag (its id, 0 without one; a white margin of two bits around it) and the affine map
        :math:`(2, 3)` from object points ``(x, y)`` to its pixels: the renderer's interface
        (:func:`~ccs_kornia.data.scenes.marker_views.render_marker_view`; ``legacy`` is a ChArUco board's and ignored)."""
        ident = self.tag_id
        side = self.bits * pixels_per_bit
        tag = cv2.aruco.generateImageMarker(aruco_dictionary(self.dictionary), int(ident or 0), side, borderBits=1)
        m = 2 * pixels_per_bit
        art = np.full((side + 2 * m, side + 2 * m), 255, dtype=np.uint8)
        art[m:m + side, m:m + side] = tag
        scale = side / float(self.size)
        return art, np.array([[scale, 0.0, m + side / 2 - 0.5], [0.0, scale, m + side / 2 - 0.5]])


def _sample(image: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Bilinear samples of a float32 image at points ``(..., 2)``."""
    flat = pts.reshape(-1, 1, 2).astype(np.float32)
    out = cv2.remap(image, flat[..., 0], flat[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(pts.shape[:-1])


def _fit_line(pts: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, float]:
    """Weighted total least-squares line ``n . x = c`` through points ``(K, 2)``."""
    c = (pts * w[:, None]).sum(0) / w.sum()
    d = pts - c
    cov = (d * w[:, None]).T @ d
    _, vecs = np.linalg.eigh(cov)
    n = vecs[:, 0]
    return n, float(n @ c)


def _intersect(l1, l2) -> np.ndarray:
    A = np.stack([l1[0], l2[0]])
    return np.linalg.solve(A, np.array([l1[1], l2[1]]))


def refine_tag_corners(image: np.ndarray, quad: np.ndarray, bits: int,
                       undistort: Callable[[np.ndarray], np.ndarray] | None = None,
                       distort: Callable[[np.ndarray], np.ndarray] | None = None,
                       rounds: int = 2) -> tuple[np.ndarray | None, str]:
    """The black square's corners ``(4, 2)`` (in the quad's order) from its sides' edges (module doc, step 2).

    Args:
        image: ``(H, W)`` grey image (any numeric type).
        quad: ``(4, 2)`` the square's corners in order around it (OpenCV's marker order).
        bits: bits across the black square.
        undistort, distort: the lens's maps of pixels ``(K, 2)`` to ideal (pinhole) pixels and back, to fit the
            sides as straight lines where the lens bends them (``None``: fit them as they are).
        rounds: measure the sides this many times, each time along the last round's sides.

    Returns:
        ``(corners, "")``, or ``(None, reason)`` when a side could not be measured.

    Example:
        >>> img = np.full((60, 60), 230.0); img[20:40, 15:45] = 20.0
        >>> c, why = refine_tag_corners(img, np.array([[15.0, 20], [44, 21], [44, 39], [14, 39]]), 8)
        >>> truth = np.array([[14.5, 19.5], [44.5, 19.5], [44.5, 39.5], [14.5, 39.5]])  # the dark block's corners
        >>> bool(np.abs(c - truth).max() < 0.05), why
        (True, '')
    """
    img = np.asarray(image, dtype=np.float32)
    corners = np.asarray(quad, dtype=np.float64).copy()
    centre = corners.mean(0)
    for _ in range(rounds):
        lines = []
        sides = np.linalg.norm(np.roll(corners, -1, 0) - corners, axis=1)
        if not np.isfinite(sides).all() or sides.min() < 8:
            return None, "tag too small to place its corners (a side under 8 px)"
        bit = float(sides.mean()) / bits
        for k in range(4):
            a, b = corners[k], corners[(k + 1) % 4]
            length = float(sides[k])
            t = np.linspace(0.08, 0.92, max(8, int(length / 1.5)))
            along = a[None] + t[:, None] * (b - a)[None]
            normal = np.array([-(b - a)[1], (b - a)[0]]) / length
            if normal @ (0.5 * (a + b) - centre) < 0:
                normal = -normal  # outward: from the black square to the white margin
            half = SEARCH_BITS * bit
            step = min(0.25, half / 8)
            offs = np.arange(-half, half + step / 2, step)
            prof = _sample(img, along[:, None, :] + offs[None, :, None] * normal[None, None, :])  # (K, S)
            grad = prof[:, 2:] - prof[:, :-2]  # derivative outward (black to white: positive)
            j = np.argmax(grad, axis=1)
            inner = (j > 0) & (j < grad.shape[1] - 1)
            rows = np.arange(len(t))
            g1 = grad[rows, j]
            # the edge: the centroid of the positive derivative within a window around its peak (a sharp edge's
            # derivative is flat between two pixel centres, a blurred one's a bump: the centroid is its middle either
            # way)
            x = offs[1:-1]
            win = np.abs(x[None, :] - x[j][:, None]) <= min(0.3 * bit, 2.0)
            wg = np.where(win, np.clip(grad, 0, None), 0.0)
            pos = (wg * x[None]).sum(1) / np.maximum(wg.sum(1), 1e-12)
            contrast = prof.max(1) - prof.min(1)
            # an edge: its steepest slope (per px) at least a tenth of its contrast, the contrast a twentieth of the image's
            keep = inner & (g1 / (2 * step) > 0.1 * contrast) & (contrast > 0.05 * max(float(img.max() - img.min()), 1e-6))
            if keep.sum() < 4:
                return None, "a side of the tag shows no clear edge (blur, glare or an occluder)"
            pts = along[keep] + pos[keep, None] * normal[None]
            if undistort is not None:
                pts = undistort(pts)
            lines.append(_fit_line(pts, g1[keep].astype(np.float64)))
        new = np.stack([_intersect(lines[(k - 1) % 4], lines[k]) for k in range(4)])
        if distort is not None:
            new = distort(new)
        corners = new
    return corners, ""


def _decode(gray8: np.ndarray, detector) -> tuple[list[np.ndarray], list[int]]:
    pts, ids, _ = detector.detectMarkers(gray8)
    if ids is None:
        return [], []
    return [p.reshape(4, 2).astype(np.float64) for p in pts], [int(i) for i in ids.ravel()]


def _detector(target: AprilTagTarget):
    params = cv2.aruco.DetectorParameters()
    params.markerBorderBits = 1
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE
    return cv2.aruco.ArucoDetector(aruco_dictionary(target.dictionary), params)


def detect_apriltag(
    images: torch.Tensor,
    target: AprilTagTarget,
    undistort: Callable[[np.ndarray], np.ndarray] | None = None,
    distort: Callable[[np.ndarray], np.ndarray] | None = None,
) -> DetectionResult:
    r"""The target tag's four corners on a batch of images (module doc).

    Args:
        images: :math:`(B, 1, H, W)` grey images in ``[0, 1]``.
        target: the :class:`AprilTagTarget` (without ``tag_id``: the id found in most images).
        undistort, distort: the lens's pixel maps (:func:`refine_tag_corners`).

    Returns:
        :class:`~ccs_kornia.modules.detection.base.DetectionResult`: corners :math:`(B, 4, 2)` in the target's grid
        order, ``found``, and per image how it was found or why not.

    Example:
        >>> from ccs_kornia.data.scenes.marker_views import render_marker_view
        >>> t = AprilTagTarget("36h11", 0.05, tag_id=3)
        >>> k = np.array([[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]])
        >>> img, truth = render_marker_view(t, np.array([0.2, -0.1, 0.05]), np.array([0.01, 0.0, 0.3]), k,
        ...                                 np.zeros(5), size=(320, 240), supersample=2)
        >>> det = detect_apriltag(torch.from_numpy(img)[None, None] / 255.0, t)
        >>> bool(det.found[0]), float(np.abs(det.corners[0].numpy() - truth).max()) < 0.1
        (True, True)
    """
    check_grey_images(images)
    B = images.shape[0]
    detector = _detector(target)
    decoded = []
    for b in range(B):
        gray8 = np.clip(np.round(images[b, 0].detach().float().cpu().numpy() * 255.0), 0, 255).astype(np.uint8)
        decoded.append((gray8, *_decode(gray8, detector)))
    ident = target.tag_id
    if ident is None:
        counts = Counter(i for _, _, ids in decoded for i in set(ids))
        ident = counts.most_common(1)[0][0] if counts else None
    corners = torch.zeros(B, 4, 2, dtype=torch.float64)
    found = torch.zeros(B, dtype=torch.bool)
    reasons = []
    for b, (gray8, quads, ids) in enumerate(decoded):
        if ident is None or ident not in ids:
            seen = f" (tags {sorted(set(ids))} seen)" if ids else ""
            reasons.append(f"AprilTag {target.family} id {ident if ident is not None else '?'} not found{seen}")
            continue
        quad = quads[ids.index(ident)]
        refined, why = refine_tag_corners(gray8, quad, target.bits, undistort, distort)
        if refined is None:
            reasons.append(why)
            continue
        bit = float(np.linalg.norm(quad - np.roll(quad, -1, 0), axis=1).mean()) / target.bits
        shift = float(np.linalg.norm(refined - quad, axis=1).max())
        if not np.isfinite(refined).all() or shift > MAX_SHIFT_BITS * bit + 1.5:
            reasons.append(f"tag corners refused: they moved {shift:.1f} px from OpenCV's")
            continue
        # OpenCV's order (top left, top right, bottom right, bottom left) to the grid's
        corners[b] = torch.from_numpy(refined[[0, 1, 3, 2]])
        found[b] = True
        reasons.append(f"apriltag {target.family} id {ident}")
    return DetectionResult(corners, found, reasons)


def _lens_maps(camera: Camera):
    """Pixel maps of the camera's lens (distorted -> ideal pixels and back) for the tag's straight sides; ``None``
    for a lens without distortion."""
    cam = camera.to("cpu", torch.float64)
    if bool(cam.straight()[0]):
        return None, None

    def undistort(pts: np.ndarray) -> np.ndarray:
        return cam.undistort(torch.from_numpy(np.asarray(pts, dtype=np.float64))[None], P=cam.K)[0].numpy()

    def distort(pts: np.ndarray) -> np.ndarray:
        return cam.distort(torch.from_numpy(np.asarray(pts, dtype=np.float64))[None], P=cam.K)[0].numpy()

    return undistort, distort


class AprilTagDetector(ChessboardDetector):
    """The single tag with the chessboard detectors' interface, so that the calibration pipeline drives it (its
    sources, batches and worker processes, ``calibrate=False``: a single tag does not calibrate a camera):
    ``board_size`` is the target's ``(2, 2)``.

    Each image is detected alone (:func:`detect_apriltag` on it): without the target's id every image gives its own
    tag, whatever the batches. It decodes and refines at full resolution (``selects_scale``: the pipeline does not
    downscale its images).

    Args:
        target: the :class:`AprilTagTarget` (its :attr:`board`).
        camera: the camera whose lens straightens the tag's sides (its pixel maps, :func:`refine_tag_corners`);
            ``None``: the sides are fitted on the image as it is.

    Example:
        >>> det = AprilTagDetector(AprilTagTarget("36h11", 0.048))
        >>> det.target.dictionary, det(torch.zeros(2, 1, 64, 64)).found.tolist()
        ('DICT_APRILTAG_36h11', [False, False])
    """

    selects_scale = True

    def __init__(self, target: AprilTagTarget, camera: Camera | None = None) -> None:
        super().__init__()
        self.target = target
        self.camera = camera

    @property
    def board(self) -> AprilTagTarget:
        """The target."""
        return self.target

    def forward(self, images: torch.Tensor, board_size: tuple[int, int] | None = None) -> DetectionResult:
        board_size = self._check_inputs(images, self.target.board_size if board_size is None else board_size)
        if board_size != self.target.board_size:
            raise ValueError(f"board_size {board_size} is not a single tag's corner grid {self.target.board_size}.")
        undistort, distort = (None, None) if self.camera is None else _lens_maps(self.camera)
        if images.shape[0] < 2:
            return detect_apriltag(images, self.target, undistort, distort)
        each = [detect_apriltag(images[b:b + 1], self.target, undistort, distort) for b in range(images.shape[0])]
        return DetectionResult(torch.cat([d.corners for d in each]), torch.cat([d.found for d in each]),
                               [r for d in each for r in d.reasons])
