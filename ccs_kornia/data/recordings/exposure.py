"""One exposure of a moving board: the image a rolling-shutter camera records (with motion blur) and where each
corner really lands.

**Image** (:func:`render_exposure`). Row ``y`` of the frame starting at ``s`` integrates the scene over
``[s + y * line_time, s + y * line_time + exposure]``: the exposure is cut into ``n`` equal sub-exposures and each is
rendered at its middle, every row with the board's pose at its own time (a per-row homography from the ray of each
pixel to the board's plane), then averaged. A still board, or ``n = 1``, gives the sharp image at mid-exposure; ``n``
is chosen per frame so that the board moves at most ``blur_step`` pixels between sub-exposures
(:func:`exposure_subframes`), so blur costs nothing where the board rests. Only the pixels that the board can cover
during the frame (the box around its outline at nine instants, padded by the motion between them) are rendered; the
rest is the background. Each pixel's footprint on the board comes from the exact derivatives of its ray (cached per
camera) through the homography, so anti-aliasing is exact under distortion and rolling shutter alike.

**Truth** (:func:`exposure_truth`). A point is imaged on the row ``y`` that solves ``y = proj_y(pose(s + y *
line_time + exposure / 2))``: the middle of its own row's exposure; solved by fixed-point iterations (each contracts by
the point's image speed times ``line_time``, a few hundredths at most). Visible: in front of the camera, where the
lens images it, inside the image, on the board's printed side.

Example:
    >>> import torch
    >>> from ccs_kornia.data.recordings.handheld import sample_handheld_trajectory
    >>> from ccs_kornia.data.recordings.patterns import ChessPattern
    >>> from ccs_kornia.data.recordings.recording_camera import RecordingCamera
    >>> cam = RecordingCamera(torch.tensor([[300.0, 0, 159.5], [0, 300, 119.5], [0, 0, 1]]), (320, 240),
    ...                       line_time=50e-6)
    >>> board = ChessPattern(6, 4, 0.03)
    >>> traj = sample_handheld_trajectory([cam], board, duration=2.0, seed=0)
    >>> truth = exposure_truth(cam, board, traj, cam.frame_starts(3))
    >>> truth.corners.shape, truth.visible.shape, truth.subframes.shape
    (torch.Size([3, 24, 2]), torch.Size([3, 24]), torch.Size([3]))
    >>> img = render_exposure(cam, board, traj, float(cam.frame_starts(1)[0]), torch.full((240, 320), 0.5),
    ...                       int(truth.subframes[0]))
    >>> img.shape
    torch.Size([240, 320])
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ccs_kornia.data.recordings.handheld import BoardTrajectory
from ccs_kornia.data.recordings.patterns import BoardPattern
from ccs_kornia.data.recordings.recording_camera import PixelRays, RecordingCamera
from ccs_kornia.data.render.lens import FAR_BOARD_COORDINATE
from ccs_kornia.geometry.so3 import log_so3

__all__ = ["MAX_SUBFRAME_PIXELS", "ExposureTruth", "exposure_subframes", "exposure_truth", "render_exposure"]

#: pixels (sub-exposures times the box's pixels) rendered at once: bounds the memory whatever the blur
MAX_SUBFRAME_PIXELS = 1 << 20


@dataclass
class ExposureTruth:
    """Exact ground truth of ``F`` frames of one camera (``N`` corners).

    Attributes:
        frame_start: :math:`(F,)` start of each frame's exposure (its first row's), s.
        frame_time: :math:`(F,)` the middle of the middle row's exposure, s: the instant of ``rvec``, ``tvec``.
        rvec, tvec: :math:`(F, 3)` the board's pose in the camera at ``frame_time`` (``x_cam = R x_board + t``).
        corners: :math:`(F, N, 2)` where each corner lands with the rolling shutter (px, NaN where not imaged).
        corner_time: :math:`(F, N)` the middle of the exposure of the row the corner lands on, s.
        visible: :math:`(F, N)` in front of the camera, imaged by the lens, inside the image, printed side seen.
        motion: :math:`(F, N, 2)` the corner's displacement over its row's exposure (px): its motion blur.
        subframes: :math:`(F,)` sub-exposures :func:`render_exposure` uses for the frame.
    """

    frame_start: Tensor
    frame_time: Tensor
    rvec: Tensor
    tvec: Tensor
    corners: Tensor
    corner_time: Tensor
    visible: Tensor
    motion: Tensor
    subframes: Tensor

    def __len__(self) -> int:
        return int(self.frame_start.shape[0])

    def __getitem__(self, index) -> ExposureTruth:
        """The truth of some frames (an index, a slice or an index tensor; an integer keeps a frame axis of 1)."""
        if isinstance(index, int):
            index = slice(index, index + 1 if index != -1 else None)
        return ExposureTruth(*(getattr(self, f)[index] for f in self.__dataclass_fields__))


def _board_points(pattern: BoardPattern, points: Tensor | None = None) -> Tensor:
    pts = pattern.outline() if points is None else points
    return torch.cat([pts[:, :2], torch.zeros(pts.shape[0], 1, dtype=torch.float64)], -1)


def _project_at(camera: RecordingCamera, trajectory: BoardTrajectory, pattern: BoardPattern, points: Tensor,
                t: Tensor):
    """Board points :math:`(N, 3)` imaged at times ``t`` :math:`(F, N)` (each point its own time), or at ``t``
    :math:`(F,)` (all points at once): pixels, ``ok``, whether the printed side is seen."""
    R, tt = camera.to_camera(*trajectory.pose_at(t))
    if t.dim() == 1:
        pc = points[None] @ R.transpose(-1, -2) + tt[:, None]
        facing = pattern.facing(R, tt)[:, None].expand(pc.shape[:2])
    else:
        pc = (R @ points[None, :, :, None]).squeeze(-1) + tt
        facing = pattern.facing(R, tt)
    pix, ok = camera.project(pc)
    return pix, ok, facing


def exposure_subframes(camera: RecordingCamera, pattern: BoardPattern, trajectory: BoardTrajectory,
                       frame_starts: Tensor, blur_step: float = 1.0, max_subframes: int = 32) -> Tensor:
    """Sub-exposures per frame: the largest displacement (px) of the board's outline and corners over the exposure
    of the first and of the last row, over ``blur_step``, rounded up, within ``[1, max_subframes]``.

    Returns:
        :math:`(F,)` long.
    """
    f = frame_starts.shape[0]
    if camera.exposure <= 0 or f == 0:
        return torch.ones(f, dtype=torch.long)
    pts = torch.cat([_board_points(pattern), pattern.object_points()])
    w, h = camera.image_size
    disp = torch.zeros(f, dtype=torch.float64)
    for row_start in (0.0, camera.readout):
        a = frame_starts + row_start
        pa, oka, _ = _project_at(camera, trajectory, pattern, pts, a)
        pb, okb, _ = _project_at(camera, trajectory, pattern, pts, a + camera.exposure)
        near = oka & okb & (pa[..., 0] > -w) & (pa[..., 0] < 2 * w) & (pa[..., 1] > -h) & (pa[..., 1] < 2 * h)
        d = torch.where(near, (pb - pa).norm(dim=-1), torch.zeros_like(pa[..., 0])).nan_to_num(0.0)
        disp = torch.maximum(disp, d.amax(-1))
    return (disp / float(blur_step)).ceil().clamp(1, int(max_subframes)).long()


def exposure_truth(camera: RecordingCamera, pattern: BoardPattern, trajectory: BoardTrajectory, frame_starts: Tensor,
                   blur_step: float = 1.0, max_subframes: int = 32, iterations: int = 10) -> ExposureTruth:
    """The exact ground truth of frames starting at ``frame_starts`` :math:`(F,)` (see the module docstring).

    Args:
        camera, pattern, trajectory: what films, what is filmed, how it moves.
        frame_starts: :math:`(F,)` float64 seconds.
        blur_step, max_subframes: of :func:`exposure_subframes`.
        iterations: most fixed-point iterations of the rolling-shutter solve (it stops at 1e-9 px).

    Returns:
        :class:`ExposureTruth`.
    """
    frame_starts = torch.as_tensor(frame_starts, dtype=torch.float64).reshape(-1)
    f = frame_starts.shape[0]
    obj = pattern.object_points()
    n = obj.shape[0]
    w, h = camera.image_size
    half = 0.5 * camera.exposure
    frame_time = camera.frame_times(frame_starts)
    t = frame_time[:, None].expand(f, n).clone()
    pix, ok, facing = _project_at(camera, trajectory, pattern, obj, t)
    if camera.line_time > 0:
        for _ in range(int(iterations)):
            y = pix[..., 1].nan_to_num(0.5 * (h - 1)).clamp(-float(h), 2.0 * h)
            t = frame_starts[:, None] + y * camera.line_time + half
            new, ok, facing = _project_at(camera, trajectory, pattern, obj, t)
            step = (new - pix).nan_to_num(0.0).abs().max()
            pix = new
            if float(step) < 1e-9:
                break
    inside = (pix[..., 0] >= 0) & (pix[..., 0] <= w - 1) & (pix[..., 1] >= 0) & (pix[..., 1] <= h - 1)
    visible = ok & facing & inside & pix.isfinite().all(-1)
    before, _, _ = _project_at(camera, trajectory, pattern, obj, t - half)
    after, _, _ = _project_at(camera, trajectory, pattern, obj, t + half)
    motion = torch.where(ok[..., None], after - before, torch.full_like(pix, math.nan))
    R, tt = camera.to_camera(*trajectory.pose_at(frame_time))
    return ExposureTruth(
        frame_start=frame_starts, frame_time=frame_time, rvec=log_so3(R), tvec=tt,
        corners=torch.where(ok[..., None], pix, torch.full_like(pix, math.nan)), corner_time=t, visible=visible,
        motion=motion, subframes=exposure_subframes(camera, pattern, trajectory, frame_starts, blur_step, max_subframes),
    )


def _board_box(camera: RecordingCamera, pattern: BoardPattern, trajectory: BoardTrajectory, frame_start: float,
               pad: float) -> tuple[int, int, int, int] | None:
    """Rows ``y0:y1`` and columns ``x0:x1`` the board can cover during the frame (``None``: none)."""
    w, h = camera.image_size
    ts = frame_start + torch.linspace(0.0, camera.readout + camera.exposure, 9, dtype=torch.float64)
    pix, ok, _ = _project_at(camera, trajectory, pattern, _board_points(pattern), ts)
    if not bool(ok.all()):
        # part of the outline is behind the camera or beyond the lens' reach: its image is not bounded by the
        # projected points; render everything unless the whole board is behind the camera
        R, tt = camera.to_camera(*trajectory.pose_at(ts))
        z = (_board_points(pattern)[None] @ R.transpose(-1, -2) + tt[:, None])[..., 2]
        return (0, h, 0, w) if bool((z > 0).any()) else None
    step = (pix[1:] - pix[:-1]).norm(dim=-1).max() if ts.numel() > 1 else torch.tensor(0.0)
    margin = float(step) + pad
    lo, hi = pix.reshape(-1, 2).amin(0) - margin, pix.reshape(-1, 2).amax(0) + margin
    x0, y0 = max(0, math.floor(float(lo[0]))), max(0, math.floor(float(lo[1])))
    x1, y1 = min(w, math.ceil(float(hi[0])) + 1), min(h, math.ceil(float(hi[1])) + 1)
    return (y0, y1, x0, x1) if x0 < x1 and y0 < y1 else None


def _mul(a: Tensor, field: Tensor) -> Tensor | None:
    """``a * field``, or ``None`` where ``field`` is a constant zero (a pinhole's derivatives)."""
    if field.dim() == 0 and float(field) == 0.0:
        return None
    return a * field


def _sum(*terms: Tensor | None) -> Tensor:
    out = None
    for t in terms:
        if t is not None:
            out = t if out is None else out + t
    return out


def _plane_coordinates(G: Tensor, rays: PixelRays):
    """Board-plane coordinates ``X, Y`` :math:`(B, h, w)` of the rays through per-row inverse homographies ``G``
    :math:`(B, h, 3, 3)`, their derivatives per pixel (the homography's derivative along the ray, chained with the
    ray's along the image) and where the plane is hit in front of the camera."""
    g = G.unsqueeze(-3)  # (B, h, 1, 3, 3): broadcasts over the columns
    q = [g[..., i, 0] * rays.x + g[..., i, 1] * rays.y + g[..., i, 2] * rays.z for i in range(3)]
    # the third component is 1 / depth along the ray: positive where the plane is hit in front of the camera
    valid = (q[2] > 1e-12) & rays.reach
    every = bool(valid.all())
    inv = 1.0 / (q[2] if every else torch.where(valid, q[2], torch.ones_like(q[2])))
    X, Y = q[0] * inv, q[1] * inv
    # d(X, Y) / d(ray): rows of (G[:2] - (X, Y) G[2]) / q2
    dX = [(g[..., 0, k] - X * g[..., 2, k]) * inv for k in range(3)]
    dY = [(g[..., 1, k] - Y * g[..., 2, k]) * inv for k in range(3)]
    pinhole = rays.z_px.dim() == 0 and float(rays.z_px) == 0.0 and rays.z_py.dim() == 0 and float(rays.z_py) == 0.0
    if pinhole:
        dX, dY = dX[:2], dY[:2]
    ray_px = (rays.x_px, rays.y_px, rays.z_px)
    ray_py = (rays.x_py, rays.y_py, rays.z_py)
    jac = tuple(_sum(*(_mul(d[k], r[k]) for k in range(len(d)))) for d in (dX, dY) for r in (ray_px, ray_py))
    jac = (jac[0], jac[1], jac[2], jac[3])  # dX/dx, dX/dy, dY/dx, dY/dy
    jac = tuple(j.expand_as(X) for j in jac)
    if not every:
        far, zero = torch.full_like(X, FAR_BOARD_COORDINATE), torch.zeros_like(X)
        X, Y = torch.where(valid, X, far), torch.where(valid, Y, far)
        jac = tuple(torch.where(valid, j, zero) for j in jac)
    return X, Y, jac, valid


def render_exposure(camera: RecordingCamera, pattern: BoardPattern, trajectory: BoardTrajectory, frame_start: float,
                    background: Tensor, subframes: int = 1, supersample: int = 2,
                    max_pixels: int | None = None) -> Tensor:
    """The linear image (before noise and tone curve) of the frame that starts at ``frame_start``.

    Args:
        camera, pattern, trajectory: what films, what is filmed, how it moves.
        frame_start: start of the frame's exposure (its first row's), s.
        background: :math:`(H, W)` float32 grey levels behind the board (black outside the lens' image circle).
        subframes: sub-exposures (:func:`exposure_subframes`; ``1``: the sharp image at mid-exposure).
        supersample: the pattern's sub-cells per pixel side on its edges.
        max_pixels: pixels rendered at once (default :data:`MAX_SUBFRAME_PIXELS`).

    Returns:
        :math:`(H, W)` float32 in ``[0, 1]``.
    """
    w, h = camera.image_size
    if tuple(background.shape) != (h, w):
        raise ValueError(f"background must be ({h}, {w}), got {tuple(background.shape)}.")
    n = max(1, int(subframes))
    out = background.to(torch.float32).clone()
    box = _board_box(camera, pattern, trajectory, float(frame_start), pad=3.0)
    if box is None:
        return out
    y0, y1, x0, x1 = box
    rays = camera.rays.crop(y0, y1, x0, x1)
    bg = out[y0:y1, x0:x1][None]
    rows = torch.arange(y0, y1, dtype=torch.float64)
    offsets = (torch.arange(n, dtype=torch.float64) + 0.5) / n * camera.exposure
    limit = MAX_SUBFRAME_PIXELS if max_pixels is None else int(max_pixels)
    chunk = max(1, limit // ((y1 - y0) * (x1 - x0)))
    acc = torch.zeros(y1 - y0, x1 - x0, dtype=torch.float32)
    for j in range(0, n, chunk):
        times = camera.row_times(float(frame_start), rows[None], offsets[j:j + chunk, None])  # (b, h)
        R, t = camera.to_camera(*trajectory.pose_at(times))
        M = torch.stack([R[..., :, 0], R[..., :, 1], t], -1)
        G, info = torch.linalg.inv_ex(M)
        G = torch.where((info == 0)[..., None, None], G, torch.zeros_like(G)).to(torch.float32)
        front = pattern.facing(R, t)[:, (y1 - y0) // 2]
        X, Y, jac, valid = _plane_coordinates(G, rays)
        acc += pattern.shade(X, Y, jac, valid, bg, supersample, front).sum(0)
    img = torch.where(rays.reach, acc / n, torch.zeros_like(acc))
    out[y0:y1, x0:x1] = img.clamp(0.0, 1.0)
    return out
