r"""Guided capture: which live frames to keep, what the calibration's predicted uncertainty is, and where the board
should go next.

:class:`GuidedCapture` is shown the frames of a camera one at a time (:meth:`GuidedCapture.offer`, grey ``uint8``)
and keeps a frame when

1. the **board is seen** by the quick screen (:class:`~ccs_kornia.modules.detection.screening.BoardScreen`, the
   recordings' screening pass);
2. it is **still**: its outline moved at most ``still`` image diagonals per second since the frame before (the frame
   selection's :data:`~ccs_kornia.pipeline.frame_selection.SPEED_SCALE`: half a view's information is lost above it);
3. it is **new**: not a near copy of a kept frame (:func:`~ccs_kornia.pipeline.frame_selection.near_copies` on the
   outlines, :data:`~ccs_kornia.pipeline.frame_selection.MIN_CHANGE`);
4. it **lowers the predicted uncertainty**: the worst 1-sigma projection uncertainty over the image
   (:func:`~ccs_kornia.modules.calibration.quality.next_pose.worst_uncertainty`) with the frame's information (its
   board pose from the outline and the current camera) is at least ``min_gain`` lower than without;
5. the detector finds its corners.

Each kept frame's corners are solved again with the ones before (``live_model``, no RANSAC) from ``min_views`` kept
frames on; the information of the views at that solve gives the figure and the next best pose
(:func:`~ccs_kornia.modules.calibration.quality.next_pose.next_poses`). Before the first solve they come from a
guessed camera whose focal length and barrel are taken from the frames kept so far (:func:`guess_camera`). The
capture is **done** once the figure is at most ``target`` px. Nothing here reads a camera or writes a file: the
``capture`` command does.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np
import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.calibration.homography import find_homographies
from ccs_kornia.modules.calibration.quality.next_pose import (
    MIN_SEEN,
    PoseSuggestion,
    candidate_poses,
    next_poses,
    uncertainty_map,
    worst_uncertainty,
)
from ccs_kornia.modules.calibration.quality.view_information import view_information
from ccs_kornia.modules.calibration.radial_guess import (
    radial_from_views,
    radial_polynomial_from_division,
)
from ccs_kornia.modules.calibration.zhang import (
    rotation_translation_from_homography,
    zhang_intrinsics,
)
from ccs_kornia.modules.detection.screening import BoardScreen, Sighting
from ccs_kornia.pipeline.frame_selection import MIN_CHANGE, SPEED_SCALE, near_copies

__all__ = ["MIN_GAIN", "MIN_TILT_DEG", "MIN_VIEWS", "CaptureDecision", "GuidedCapture", "KeptFrame", "guess_camera"]

#: a frame must lower the predicted worst uncertainty by at least this fraction to be kept
MIN_GAIN = 0.02
#: kept frames before the first solve (the predicted figure comes from the solve)
MIN_VIEWS = 4
#: a guess takes its focal length from the views kept where one of them is turned at least this far from facing the
#: camera (degrees, at that focal length): a board held flat leaves the focal length undetermined
MIN_TILT_DEG = 5.0
def guess_camera(model: CameraModel, image_size: tuple[int, int], corners: torch.Tensor | None = None,
                 object_points: torch.Tensor | None = None) -> Camera:
    """The camera assumed before the first solve: the model's kind, a focal length of the image's longer side (a
    fisheye: a third of it, about 180 degrees across), the principal point at the centre, no distortion.

    Given the views kept so far (``corners`` :math:`(V, N, 2)`, NaN where not seen, of ``object_points``
    :math:`(N, 3)`), a lens that is not a fisheye takes its radial distortion and its focal length from them
    instead: the radial distortion about the image centre that straightens the boards (:func:`radial_from_views`,
    as the model's ``k1, k2`` where it has them), then the focal length from the straightened boards' homographies
    (Zhang's closed form, the principal point at the centre, ``fx = fy``; one tilted view suffices). A wide lens's
    focal length is far from the image's side and its barrel pulls the boards in: the poses laid out for a pinhole
    of the image's side put the board small and near the image centre. A view that tells nothing about the focal
    length (every board held within :data:`MIN_TILT_DEG` of flat) keeps the default.

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.models import OPENCV5
        >>> obj = board_object_points(9, 6, 0.025, dtype=torch.float64)
        >>> truth = Camera(OPENCV5, torch.tensor([330.0, 330, 319.5, 239.5, 0, 0, 0, 0, 0], dtype=torch.float64),
        ...                (640, 480))
        >>> R = torch.tensor([[1.0, 0, 0], [0, 0.8, -0.6], [0, 0.6, 0.8]], dtype=torch.float64)  # tilted
        >>> uv = truth.project((obj @ R.T + torch.tensor([-0.1, -0.06, 0.4], dtype=torch.float64))[None])
        >>> round(float(guess_camera(OPENCV5, (640, 480)).params[0, 0]))
        640
        >>> round(float(guess_camera(OPENCV5, (640, 480), uv, obj).params[0, 0]))
        330
    """
    W, H = image_size
    f = max(W, H) / (3.0 if model.is_fisheye else 1.0)
    radial = None
    if corners is not None and object_points is not None and not model.is_fisheye and len(corners):
        uv = torch.as_tensor(corners, dtype=torch.float64)
        valid = uv.isfinite().all(-1)
        kappa = radial_from_views(uv, object_points, image_size)
        c = torch.tensor([(W - 1) / 2, (H - 1) / 2], dtype=torch.float64)
        d = uv.nan_to_num(0.0) - c
        straight = c + d / (1 + kappa * (d * d).sum(-1, keepdim=True) / c.pow(2).sum())
        Hs, ok = find_homographies(object_points.double()[:, :2], straight, valid, return_ok=True)
        K, good = zhang_intrinsics(Hs, ok & (valid.sum(-1) >= 8), image_size, principal_point="centre",
                                   fix_aspect_ratio=True, return_ok=True)
        est = float(K[0, 0])
        used = ok & (valid.sum(-1) >= 8)
        R, _ = rotation_translation_from_homography(K, Hs)
        tilted = bool((R[..., 2, 2].abs()[used] < math.cos(math.radians(MIN_TILT_DEG))).any())
        if bool(good) and tilted and math.isfinite(est) and 0.1 * max(W, H) < est < 10 * max(W, H):
            f = est
        names = model.param_names
        if kappa != 0.0 and "k1" in names and "k2" in names:
            radial = radial_polynomial_from_division(kappa, f, image_size)
    params = torch.zeros(model.num_params, dtype=torch.float64)
    params[:4] = torch.tensor([f, f, (W - 1) / 2, (H - 1) / 2], dtype=torch.float64)
    if radial is not None:
        params[model.param_names.index("k1")], params[model.param_names.index("k2")] = radial
    return Camera(model, params, (int(W), int(H)))


@dataclass
class KeptFrame:
    """A frame kept: its index and time in the stream, its corners :math:`(N, 2)` (NaN: not seen), its outline and
    why it was kept (the figure before and after it)."""

    index: int
    timestamp: float
    corners: np.ndarray
    outline: np.ndarray
    why: str


@dataclass
class CaptureDecision:
    """What :meth:`GuidedCapture.offer` made of one frame.

    Attributes:
        kept: the frame was kept.
        reason: why it was kept, or why not (``"no board"``, ``"moving"``, ``"near copy of frame 12"``, ``"adds
            little (1 %)"``, ``"corners not found"``).
        sighting: the screen's look at it.
        worst_px: the predicted worst 1-sigma projection uncertainty over the image now (``inf`` before the first
            solve).
        done: the target is reached.
    """

    kept: bool
    reason: str
    sighting: Sighting
    worst_px: float
    done: bool


@dataclass
class GuidedCapture:
    """The live capture's state for one camera (see the module docstring).

    Args:
        board_size: ``(cols, rows)`` inner corners.
        object_points: :math:`(N, 3)` the board's corners by id.
        image_size: ``(W, H)``.
        detect: grey ``uint8`` frame -> corners :math:`(N, 2)` float64 (NaN where not seen) or ``None``.
        screen: the quick look (default: a chessboard's :class:`BoardScreen`).
        live_model: the model solved live.
        target: the worst 1-sigma (px) at which the capture is done.
        min_gain, still, min_change, min_views: :data:`MIN_GAIN`, :data:`SPEED_SCALE`, :data:`MIN_CHANGE`,
            :data:`MIN_VIEWS`.
        max_frames: frames kept at most (done at that count).
    """

    board_size: tuple[int, int]
    object_points: torch.Tensor
    image_size: tuple[int, int]
    detect: Callable[[np.ndarray], np.ndarray | None]
    live_model: CameraModel
    screen: BoardScreen | None = None
    target: float = 0.1
    min_gain: float = MIN_GAIN
    still: float = SPEED_SCALE
    min_change: float = MIN_CHANGE
    min_views: int = MIN_VIEWS
    max_frames: int = 40
    kept: list[KeptFrame] = field(default_factory=list)
    camera: Camera | None = None
    information: torch.Tensor | None = None
    sigma: float = 0.5
    worst_px: float = math.inf
    sightings: int = 0
    _last: tuple[float, np.ndarray] | None = None
    _solved: bool = False

    def __post_init__(self) -> None:
        self.object_points = self.object_points.double()
        if self.screen is None:
            self.screen = BoardScreen(self.board_size)
        self.camera = guess_camera(self.live_model, self.image_size)
        P = self.live_model.num_params
        self.information = torch.zeros(P, P, dtype=torch.float64)
        cols, rows = self.board_size
        self._ends = [0, cols - 1, cols * rows - 1, cols * (rows - 1)]
        # boards partly beyond the image's edge are asked for only where the screen sees them
        self._min_seen = MIN_SEEN if getattr(self.screen, "sees_partial_boards", False) else 1.0
        self._candidates = candidate_poses(self.camera, self.object_points, self.board_size, min_seen=self._min_seen)

    @property
    def diagonal(self) -> float:
        return math.hypot(*self.image_size)

    @property
    def done(self) -> bool:
        return len(self.kept) >= self.max_frames or (self._solved and self.worst_px <= self.target)

    def _pose(self, points: np.ndarray, ids: list[int]) -> tuple[torch.Tensor, torch.Tensor] | None:
        """The board's pose from image points of the given corner ids, through the current camera's rays."""
        rays = self.camera.unproject(torch.as_tensor(points, dtype=torch.float64)[None])[0]
        if not bool(rays.isfinite().all()) or not bool((rays[:, 2] > 1e-6).all()):
            return None
        xy = (rays[:, :2] / rays[:, 2:]).numpy()
        obj = self.object_points[ids].numpy()
        flag = cv2.SOLVEPNP_IPPE if len(ids) == 4 else cv2.SOLVEPNP_ITERATIVE
        ok, r, t = cv2.solvePnP(obj, xy, np.eye(3), None, flags=flag)
        if not ok or not np.isfinite(r).all() or float(t[2, 0]) <= 0:
            return None
        return torch.from_numpy(r.reshape(1, 1, 3)).double(), torch.from_numpy(t.reshape(1, 1, 3)).double()

    def _view_information(self, rvec: torch.Tensor, tvec: torch.Tensor, valid: torch.Tensor | None = None):
        """The information of views at ``rvec, tvec`` :math:`(1, V, 3)`, of the corners ``valid`` :math:`(V, N)`
        (default: those the pose puts inside the image)."""
        if valid is None:
            pts = torch.einsum("vij,nj->vni", exp_so3(rvec[0]), self.object_points) + tvec[0, :, None]
            uv = self.camera.project(pts.reshape(1, -1, 3))[0].reshape(*pts.shape[:2], 2)
            W, H = self.image_size
            valid = ((pts[..., 2] > 0) & (uv[..., 0] >= 0) & (uv[..., 0] <= W - 1) & (uv[..., 1] >= 0)
                     & (uv[..., 1] <= H - 1))
        return view_information(self.camera, rvec, tvec, self.object_points, valid.double()[None])[0]

    def figure(self, information: torch.Tensor, typical: torch.Tensor) -> float:
        """The worst 1-sigma projection uncertainty over the image (px) for ``information`` (``typical``: an average
        view's, the prior's scale)."""
        return float(worst_uncertainty(self.camera, information, self.sigma, typical=typical))

    def offer(self, gray8: np.ndarray, index: int, timestamp: float) -> CaptureDecision:
        """Look at one frame (grey ``uint8``, full size) and keep it or say why not."""
        seen = self.screen(gray8)
        last, self._last = self._last, ((timestamp, seen.outline) if seen.found else None)

        def no(reason: str) -> CaptureDecision:
            return CaptureDecision(False, reason, seen, self.worst_px, self.done)

        if not seen.found:
            return no("no board")
        self.sightings += 1
        if last is None or timestamp <= last[0]:
            return no("moving")
        speed = float(np.linalg.norm(seen.outline - last[1], axis=-1).mean()) / (timestamp - last[0])
        if speed > self.still * self.diagonal:
            return no(f"moving ({speed:.0f} px/s)")
        if self.kept:
            outlines = torch.as_tensor(np.stack([k.outline for k in self.kept] + [seen.outline]))
            copies = near_copies(outlines, torch.ones(outlines.shape[:2], dtype=torch.bool), self.min_change)[-1]
            if bool(copies.any()):
                return no(f"near copy of frame {self.kept[int(copies.nonzero()[0])].index}")
        pose = self._pose(seen.outline, self._ends)
        if pose is None:
            return no("no pose")
        added = self.information + self._view_information(*pose).sum(0)
        typical = added / (len(self.kept) + 1)
        before = self.figure(self.information, typical) if len(self.kept) else math.inf
        after = self.figure(added, typical)
        gain = 1.0 - after / before if math.isfinite(before) else 1.0
        if gain < self.min_gain:
            return no(f"adds little ({100 * gain:.0f} %)")
        corners = self.detect(gray8)
        if corners is None or np.isfinite(corners).all(-1).sum() < 4:
            return no("corners not found")
        why = ("the first view" if not self.kept else
               f"lowers the predicted worst uncertainty {before:.3g} -> {after:.3g} px ({100 * gain:.0f} %)")
        self.kept.append(KeptFrame(index, timestamp, corners, seen.outline.copy(), why))
        self._update()
        return CaptureDecision(True, why, seen, self.worst_px, self.done)

    def keep_now(self, gray8: np.ndarray, index: int, timestamp: float, why: str = "kept by hand") -> CaptureDecision:
        """Keep this frame whatever the gates say (a person's choice, or a rig's view in common), where the board and
        its corners are found."""
        seen = self.screen(gray8)
        corners = self.detect(gray8) if seen.found else None
        if corners is None or np.isfinite(corners).all(-1).sum() < 4:
            return CaptureDecision(False, "corners not found", seen, self.worst_px, self.done)
        self.kept.append(KeptFrame(index, timestamp, corners, seen.outline.copy(), why))
        self._update()
        return CaptureDecision(True, why, seen, self.worst_px, self.done)

    def uncertainty_map(self, grid: tuple[int, int] = (16, 12)) -> np.ndarray | None:
        """The predicted worst-direction 1-sigma projection uncertainty :math:`(down, across)` px over the image
        (``None`` before the first solve)."""
        if not self._solved:
            return None
        return uncertainty_map(self.camera, self.information, self.sigma, grid,
                               typical=self.information / len(self.kept)).numpy()

    def undo(self) -> KeptFrame | None:
        """Drop the last kept frame; the calibration is solved again without it."""
        if not self.kept:
            return None
        frame = self.kept.pop()
        if len(self.kept) >= self.min_views:
            self._solve()
        else:
            self._solved, self.worst_px = False, math.inf
            self._guess()
        return frame

    def _update(self) -> None:
        if len(self.kept) >= self.min_views:
            self._solve()
        if not self._solved:
            self._guess()

    def _guess(self) -> None:
        """Before the first solve: the camera guessed from the frames kept (:func:`guess_camera`), its candidate
        poses, and the information of the kept frames at their rough poses through it."""
        corners = torch.as_tensor(np.stack([k.corners for k in self.kept])) if self.kept else None
        camera = guess_camera(self.live_model, self.image_size, corners, self.object_points)
        if not torch.equal(camera.params, self.camera.params):
            self.camera = camera
            self._candidates = candidate_poses(camera, self.object_points, self.board_size, min_seen=self._min_seen)
        self.information = torch.zeros_like(self.information)
        for k in self.kept:
            valid = np.isfinite(k.corners).all(-1)
            pose = self._pose(k.corners[valid], np.nonzero(valid)[0].tolist())
            if pose is not None:
                self.information = self.information + self._view_information(
                    *pose, torch.as_tensor(valid)[None]).sum(0)

    def _solve(self) -> None:
        from ccs_kornia.modules.calibration.solver import CalibrationSolver

        if len(self.kept) < self.min_views:
            return
        corners = torch.as_tensor(np.stack([k.corners for k in self.kept]), dtype=torch.float64)
        valid = corners.isfinite().all(-1)
        solver = CalibrationSolver(model=self.live_model, use_ransac=False, checks=False)
        res = solver(torch.where(valid[..., None], corners, torch.zeros_like(corners)), valid, self.object_points,
                     self.image_size)
        if not bool(res.success) or not bool(res.camera.params.isfinite().all()):
            return
        self.camera = Camera(res.camera.model, res.camera.params.double(), self.image_size)
        used = valid & res.used[:, None].bool()
        M = view_information(self.camera, res.rvec[None].double(), res.tvec[None].double(), self.object_points,
                             used[None].double())[0]
        self.information = M.sum(0)
        self.sigma = max(float(res.rms) / math.sqrt(2), 1e-3)
        self._solved = True
        self.worst_px = self.figure(self.information, self.information / len(self.kept))

    def suggestion(self, current_fill: float | None = None) -> PoseSuggestion:
        """The next best pose for the current calibration (or the guessed camera before the first solve)."""
        candidates = None if self._solved else self._candidates
        return next_poses(self.camera, self.information, self.object_points, self.sigma, self.board_size,
                          candidates=candidates, current_fill=current_fill, top=5, min_seen=self._min_seen)
