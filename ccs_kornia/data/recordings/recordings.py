"""Rendered recordings of a hand-held board, for one camera or a rig, with exact ground truth.

A :class:`Recording` is one camera filming a board that moves along a trajectory: its frames are rendered one at a
time when asked for (:meth:`Recording.frames` streams them, so a minute of 1280x720 video never sits in memory), with
a rolling shutter, motion blur, sensor noise and the camera's lens (:mod:`ccs_kornia.data.recordings.exposure`); its ground truth
(:attr:`Recording.truth`) needs no rendering. A :class:`RigRecording` is several such cameras filming the same board,
each with its own clock: its own frame rate, phase, exposure, readout, and logged timestamps that carry a latency and
a software-sync jitter; :meth:`RigRecording.sync_table` pairs their frames by those timestamps as a recording program
does (caliscope's ``sync_index, cam_id, frame_index, frame_time``).

:func:`webcam` and :func:`webcam_rig` draw ordinary webcams (60-75 degrees across, mild OpenCV distortion, a rolling
shutter that reads the frame in half to 90 % of its period, exposures of 8-20 ms); :func:`handheld_recording` and
:func:`handheld_rig_recording` put a board in their hands. Everything is fixed by the seed.

Example:
    >>> from ccs_kornia.data.recordings.patterns import ChessPattern
    >>> rec = handheld_recording(webcam((320, 240), seed=0), ChessPattern(6, 4, 0.03), duration=1.0, seed=0)
    >>> len(rec), rec.truth.corners.shape
    (28, torch.Size([28, 24, 2]))
    >>> index, image = next(rec.frames())
    >>> index, image.shape, image.dtype
    (0, torch.Size([240, 320]), torch.uint8)
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from functools import cached_property

import torch
from torch import Tensor

from ccs_kornia.data.recordings.exposure import (
    ExposureTruth,
    exposure_truth,
    render_exposure,
)
from ccs_kornia.data.recordings.handheld import (
    BoardTrajectory,
    sample_handheld_trajectory,
)
from ccs_kornia.data.recordings.patterns import BoardPattern
from ccs_kornia.data.recordings.recording_camera import OpenCVLens, RecordingCamera
from ccs_kornia.data.render.augment import textured_background
from ccs_kornia.data.scenes.sampling import sample_opencv_distortion
from ccs_kornia.geometry.so3 import exp_so3

__all__ = ["Recording", "RigRecording", "handheld_recording", "handheld_rig_recording", "webcam", "webcam_rig"]


def _seed(*parts: int) -> int:
    """One 63-bit seed from several integers (a seed per camera and frame, whatever order frames are asked in)."""
    h = 1469598103934665603
    for p in parts:
        h = ((h ^ (int(p) & 0xFFFFFFFFFFFFFFFF)) * 1099511628211) & 0xFFFFFFFFFFFFFFFF
    return h & 0x7FFFFFFFFFFFFFFF


class Recording:
    """One camera filming a board that moves along ``trajectory`` (see the module docstring).

    Args:
        camera: the camera.
        pattern: the board.
        trajectory: the board's motion (e.g. :func:`~ccs_kornia.data.recordings.handheld.sample_handheld_trajectory`).
        duration: seconds recorded (default the trajectory's).
        seed: fixes the background, the noise and the logged timestamps' jitter.
        background: ``"texture"`` (procedural clutter), ``"plain"`` (grey 0.5), a grey level or an :math:`(H, W)`
            image (linear light).
        supersample: the pattern's sub-cells per pixel side on its edges.
        blur_step: the board moves at most this many pixels between the sub-exposures of a blurred frame.
        max_subframes: most sub-exposures per frame.
        stream: which camera of a rig this is (another stream of random numbers for the same seed).
    """

    def __init__(self, camera: RecordingCamera, pattern: BoardPattern, trajectory: BoardTrajectory,
                 duration: float | None = None, seed: int = 0, background: str | float | Tensor = "texture",
                 supersample: int = 2, blur_step: float = 1.0, max_subframes: int = 32, stream: int = 0) -> None:
        self.camera, self.pattern, self.trajectory = camera, pattern, trajectory
        self.duration = trajectory.duration if duration is None else float(duration)
        if not 0 < self.duration <= trajectory.duration + 1e-9:
            raise ValueError(f"duration must be in (0, {trajectory.duration:.3f}] (the trajectory's), got {duration}.")
        if int(supersample) < 1 or not blur_step > 0 or int(max_subframes) < 1:
            raise ValueError("supersample and max_subframes must be >= 1 and blur_step positive.")
        self.seed, self.stream = int(seed), int(stream)
        self.supersample, self.blur_step, self.max_subframes = int(supersample), float(blur_step), int(max_subframes)
        self.frame_start = camera.frame_starts(camera.num_frames(self.duration))
        g = torch.Generator().manual_seed(_seed(self.seed, self.stream, 1))
        n = self.frame_start.shape[0]
        #: :math:`(F,)` the timestamps a recording program logs: the frame's time, a latency and a jitter (s)
        self.timestamp = camera.frame_times(self.frame_start) + camera.latency + \
            camera.jitter * torch.randn(n, generator=g, dtype=torch.float64)
        self._background = background

    def __len__(self) -> int:
        return int(self.frame_start.shape[0])

    @cached_property
    def truth(self) -> ExposureTruth:
        """The exact ground truth of every frame (:class:`~ccs_kornia.data.recordings.exposure.ExposureTruth`)."""
        return exposure_truth(self.camera, self.pattern, self.trajectory, self.frame_start, self.blur_step,
                              self.max_subframes)

    @cached_property
    def background(self) -> Tensor:
        """:math:`(H, W)` float32 linear grey levels behind the board (black outside the lens' image circle)."""
        w, h = self.camera.image_size
        bg = self._background
        if isinstance(bg, str):
            if bg not in ("texture", "plain"):
                raise ValueError(f"background must be 'texture', 'plain', a grey level or an image; got {bg!r}.")
            g = torch.Generator().manual_seed(_seed(self.seed, self.stream, 2))
            img = textured_background(1, (w, h), g)[0, 0] if bg == "texture" else torch.full((h, w), 0.5)
        else:
            img = torch.as_tensor(bg, dtype=torch.float32)
            img = img.expand(h, w).clone() if img.dim() == 0 else img
            if tuple(img.shape) != (h, w):
                raise ValueError(f"a background image must be ({h}, {w}), got {tuple(img.shape)}.")
        return torch.where(self.camera.rays.reach, img.float(), torch.zeros_like(img, dtype=torch.float32))

    def row_poses(self, index: int) -> tuple[Tensor, Tensor]:
        """The board's pose in the camera at the middle of each row's exposure in frame ``index``: ``R``
        :math:`(H, 3, 3)`, ``t`` :math:`(H, 3)` (all equal under a global shutter)."""
        rows = torch.arange(self.camera.image_size[1], dtype=torch.float64)
        times = self.camera.row_times(float(self.frame_start[index]), rows, 0.5 * self.camera.exposure)
        return self.camera.to_camera(*self.trajectory.pose_at(times))

    def linear_image(self, index: int, subframes: int | None = None) -> Tensor:
        """Frame ``index`` in linear light, before noise and tone curve, :math:`(H, W)` float32 (``subframes``: the
        truth's unless given; ``1`` renders the sharp image at mid-exposure)."""
        n = int(self.truth.subframes[index]) if subframes is None else int(subframes)
        return render_exposure(self.camera, self.pattern, self.trajectory, float(self.frame_start[index]),
                               self.background, n, self.supersample)

    def image(self, index: int) -> Tensor:
        """Frame ``index`` as the camera records it: :math:`(H, W)` uint8 (noise, tone curve, quantisation)."""
        index = int(index)
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} of a recording of {len(self)} frames")
        img = self.linear_image(index)
        cam = self.camera
        if cam.noise > 0:
            g = torch.Generator().manual_seed(_seed(self.seed, self.stream, 3, index))
            sigma = cam.noise * (1.0 + img.clamp_min(0.0)).sqrt()  # read noise plus shot noise
            img = img + sigma * torch.randn(img.shape, generator=g)
        img = img.clamp(0.0, 1.0)
        if cam.gamma != 1.0:
            img = img.pow(1.0 / cam.gamma)
        return (img * 255.0).round().to(torch.uint8)

    def frames(self, start: int = 0, stop: int | None = None, step: int = 1) -> Iterator[tuple[int, Tensor]]:
        """Render frames ``start:stop:step`` one at a time: ``(index, image)`` pairs (:meth:`image`)."""
        for i in range(*slice(start, stop, step).indices(len(self))):
            yield i, self.image(i)

    def __iter__(self) -> Iterator[tuple[int, Tensor]]:
        return self.frames()

    def to_json(self) -> dict:
        """How the recording was made (camera, board, trajectory, seed, rendering options) as JSON."""
        return {
            "camera": self.camera.to_json(), "pattern": self.pattern.to_json(),
            "object_points": self.pattern.object_points().tolist(), "trajectory": self.trajectory.to_json(),
            "duration": self.duration, "seed": self.seed, "stream": self.stream,
            "render": {"supersample": self.supersample, "blur_step": self.blur_step,
                       "max_subframes": self.max_subframes},
        }


class RigRecording:
    """Several cameras filming the same moving board, each on its own clock (see the module docstring).

    Args:
        cameras: the rig's cameras (``x_cam = R x_rig + T``).
        pattern, trajectory, duration, seed: as :class:`Recording`'s.
        render: options of :class:`Recording` (``background``, ``supersample``, ``blur_step``, ``max_subframes``).
    """

    def __init__(self, cameras: Sequence[RecordingCamera], pattern: BoardPattern, trajectory: BoardTrajectory,
                 duration: float | None = None, seed: int = 0, **render) -> None:
        if len(cameras) < 1:
            raise ValueError("a rig needs at least one camera.")
        self.cameras = list(cameras)
        self.recordings = [Recording(c, pattern, trajectory, duration, seed, stream=i, **render)
                           for i, c in enumerate(self.cameras)]
        self.pattern, self.trajectory, self.seed = pattern, trajectory, int(seed)

    def __len__(self) -> int:
        return len(self.cameras)

    def __getitem__(self, camera: int) -> Recording:
        return self.recordings[camera]

    @property
    def extrinsics(self) -> tuple[Tensor, Tensor]:
        """Each camera's pose from camera 0: ``R`` :math:`(C, 3, 3)`, ``T`` :math:`(C, 3)`, ``x_c = R_c x_0 + T_c``
        (the convention of ``calibrate-rig``'s ``rig.json``)."""
        R0, T0 = self.cameras[0].R, self.cameras[0].T
        R = torch.stack([c.R @ R0.T for c in self.cameras])
        T = torch.stack([c.T for c in self.cameras]) - (R @ T0[:, None])[..., 0]
        return R, T

    def sync_table(self, tolerance: float | None = None) -> list[tuple[int, int, int, float]]:
        """The cameras' frames paired by their logged timestamps, as rows ``(sync_index, cam_id, frame_index,
        frame_time)``.

        The camera with the lowest frame rate (the first of those) sets the instants: ``sync_index`` is its frame
        index, and every camera contributes its frame whose timestamp is nearest, if within ``tolerance`` seconds
        (default half the reference camera's frame period) and not taken by an earlier instant. Rows come by ``sync_index``
        then ``cam_id``; ``frame_time`` is the logged timestamp.
        """
        ref = min(range(len(self)), key=lambda c: (self.cameras[c].fps, c))
        ref_ts = self.recordings[ref].timestamp
        rows: list[tuple[int, int, int, float]] = []
        picks = []
        tol = 0.5 / self.cameras[ref].fps if tolerance is None else float(tolerance)
        for rec in self.recordings:
            if rec.timestamp.numel() == 0 or ref_ts.numel() == 0:
                picks.append({})
                continue
            gap = (rec.timestamp[None, :] - ref_ts[:, None]).abs()
            near = gap.argmin(1)
            taken: set[int] = set()
            pick = {}
            for k in range(ref_ts.numel()):
                j = int(near[k])
                if float(gap[k, j]) <= tol and j not in taken:
                    taken.add(j)
                    pick[k] = j
            picks.append(pick)
        for k in range(ref_ts.numel()):
            for c, rec in enumerate(self.recordings):
                if k in picks[c]:
                    j = picks[c][k]
                    rows.append((k, c, j, float(rec.timestamp[j])))
        return rows

    def to_json(self) -> dict:
        """How the rig recording was made, and the rig's extrinsics from camera 0, as JSON."""
        R, T = self.extrinsics
        return {"cameras": [r.to_json() for r in self.recordings], "R": R.tolist(), "T": T.tolist()}


def _look_at(position: Tensor, target: Tensor, roll: float) -> tuple[Tensor, Tensor]:
    """``(R, T)`` of a camera at ``position`` looking at ``target`` (y down, turned by ``roll`` about its axis),
    ``x_cam = R x_world + T``."""
    z = torch.nn.functional.normalize(target - position, dim=0)
    down = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    x = torch.nn.functional.normalize(torch.linalg.cross(down, z), dim=0)
    y = torch.linalg.cross(z, x)
    R = exp_so3(torch.tensor([0.0, 0.0, roll], dtype=torch.float64)) @ torch.stack([x, y, z])
    return R, -R @ position


def webcam(image_size: tuple[int, int] = (1280, 720), seed: int = 0, fps: float = 30.0,
           hfov_deg: tuple[float, float] = (60.0, 75.0), rolling_shutter: bool = True, distortion: bool = True,
           exposure_ms: tuple[float, float] = (8.0, 20.0), jitter_ms: tuple[float, float] = (0.0, 0.0),
           latency_ms: tuple[float, float] = (0.0, 0.0), start_ms: tuple[float, float] | None = None,
           noise: tuple[float, float] = (0.005, 0.015), gamma: float = 2.2, R: Tensor | None = None,
           T: Tensor | None = None) -> RecordingCamera:
    """An ordinary webcam (see the module docstring); ranges are drawn uniformly from ``seed``.

    Args:
        image_size: ``(W, H)``.
        seed: fixes the draws.
        fps: frames per second.
        hfov_deg: horizontal field of view.
        rolling_shutter: read the rows in 50-90 % of the frame period (else a global shutter).
        distortion: mild OpenCV distortion (else a pinhole).
        exposure_ms, jitter_ms, latency_ms: exposure, timestamp jitter (standard deviation) and latency.
        start_ms: when the first frame starts (the camera's phase; default anywhere in the first frame period: a
            free-running camera).
        noise: sensor noise.
        gamma: tone curve.
        R, T: pose in the rig.

    Example:
        >>> cam = webcam((640, 480), seed=1)
        >>> cam.image_size, type(cam.lens).__name__, cam.line_time > 0
        ((640, 480), 'OpenCVLens', True)
    """
    g = torch.Generator().manual_seed(_seed(int(seed), 7))

    def u(lo: float, hi: float) -> float:
        return lo + (hi - lo) * float(torch.rand(1, generator=g, dtype=torch.float64))

    w, h = int(image_size[0]), int(image_size[1])
    fx = 0.5 * w / math.tan(math.radians(u(*hfov_deg)) / 2)
    K = torch.tensor([[fx, 0.0, (w - 1) / 2 + u(-0.02, 0.02) * w], [0.0, fx * u(0.995, 1.005), (h - 1) / 2 +
                      u(-0.02, 0.02) * h], [0.0, 0.0, 1.0]], dtype=torch.float64)
    lens = OpenCVLens(sample_opencv_distortion(K, (w, h), 1, g, (-0.15, 0.05), (-0.05, 0.1), 5e-4)[0]) \
        if distortion else None
    period = 1.0 / fps
    line_time = u(0.5, 0.9) * period / (h - 1) if rolling_shutter else 0.0
    exposure = min(u(*exposure_ms) * 1e-3, period)
    kw = {} if lens is None else {"lens": lens}
    start = u(0.0, period) if start_ms is None else u(*start_ms) * 1e-3
    return RecordingCamera(K, (w, h), fps=fps, exposure=exposure, line_time=line_time, start=start,
                           latency=u(*latency_ms) * 1e-3, jitter=u(*jitter_ms) * 1e-3, noise=u(*noise), gamma=gamma,
                           R=R, T=T, **kw)


def webcam_rig(num_cameras: int = 3, image_size: tuple[int, int] | Sequence[tuple[int, int]] = (1280, 720),
               seed: int = 0, fps: float | Sequence[float] = 30.0, spacing: float = 0.5, distance: float = 1.5,
               spread: float = 0.35, jitter_ms: tuple[float, float] = (2.0, 10.0),
               latency_ms: tuple[float, float] = (0.0, 15.0), **webcam_kw) -> list[RecordingCamera]:
    """Webcams side by side, ``spacing`` metres apart (with some height and depth scatter), aimed at points
    ``spread`` times the spacing apart around a spot ``distance`` metres in front of them: their fields of view
    overlap partly. The rig's frame is camera 0's.

    Args:
        num_cameras: cameras.
        image_size: one ``(W, H)`` or one per camera.
        seed: fixes the rig and every camera's draws.
        fps: one frame rate or one per camera.
        spacing, distance, spread: the layout (metres; ``spread`` relative to ``spacing``).
        jitter_ms, latency_ms: ranges of each camera's timestamp jitter and latency.
        webcam_kw: more options of :func:`webcam`.

    Example:
        >>> cams = webcam_rig(3, (640, 480), seed=0)
        >>> len(cams), cams[0].R.allclose(torch.eye(3, dtype=torch.float64)), float(cams[1].T.norm()) > 0.3
        (3, True, True)
    """
    c = int(num_cameras)
    if c < 1:
        raise ValueError(f"a rig needs at least one camera, got {num_cameras}.")
    sizes = [tuple(image_size)] * c if isinstance(image_size[0], int) else [tuple(s) for s in image_size]
    rates = [float(fps)] * c if isinstance(fps, (int, float)) else [float(f) for f in fps]
    if len(sizes) != c or len(rates) != c:
        raise ValueError(f"give one image size and one frame rate, or one per camera ({c}).")
    g = torch.Generator().manual_seed(_seed(int(seed), 11))

    def n(scale: float, k: int = 3) -> Tensor:
        return torch.randn(k, generator=g, dtype=torch.float64) * scale

    poses = []
    for i in range(c):
        offset = (i - (c - 1) / 2) * spacing
        position = torch.tensor([offset, 0.0, 0.0], dtype=torch.float64) + n(0.05)
        target = torch.tensor([offset * spread, 0.0, distance], dtype=torch.float64) + n(0.1)
        poses.append(_look_at(position, target, float(n(math.radians(3.0), 1))))
    R0, T0 = poses[0]
    cams = []
    for i, (R, T) in enumerate(poses):
        Rr = R @ R0.T
        cams.append(webcam(sizes[i], _seed(int(seed), 13, i), rates[i], jitter_ms=jitter_ms, latency_ms=latency_ms,
                           R=Rr, T=T - Rr @ T0, **webcam_kw))
    return cams


def handheld_recording(camera: RecordingCamera | None = None, pattern: BoardPattern | None = None,
                       duration: float = 60.0, seed: int = 0, trajectory: dict | None = None, **render) -> Recording:
    """A board waved in front of one camera for ``duration`` seconds.

    Args:
        camera: the camera (default :func:`webcam` of ``seed``).
        pattern: the board (default a 9x6 chessboard of 30 mm squares).
        duration: seconds.
        seed: fixes the trajectory, the noise and the background.
        trajectory: options of :func:`~ccs_kornia.data.recordings.handheld.sample_handheld_trajectory`.
        render: options of :class:`Recording`.
    """
    from ccs_kornia.data.recordings.patterns import ChessPattern

    camera = webcam(seed=seed) if camera is None else camera
    pattern = ChessPattern(9, 6, 0.03) if pattern is None else pattern
    traj = sample_handheld_trajectory([camera], pattern, duration, seed, **(trajectory or {}))
    return Recording(camera, pattern, traj, duration, seed, **render)


def handheld_rig_recording(cameras: Sequence[RecordingCamera] | None = None, pattern: BoardPattern | None = None,
                           duration: float = 60.0, seed: int = 0, trajectory: dict | None = None,
                           **render) -> RigRecording:
    """A board waved in front of a rig for ``duration`` seconds (default :func:`webcam_rig` of ``seed``, three
    1280x720 webcams, and a 9x6 chessboard of 40 mm squares); the waypoints visit the cameras in turn."""
    from ccs_kornia.data.recordings.patterns import ChessPattern

    cameras = webcam_rig(seed=seed) if cameras is None else list(cameras)
    pattern = ChessPattern(9, 6, 0.04) if pattern is None else pattern
    traj = sample_handheld_trajectory(cameras, pattern, duration, seed, **(trajectory or {}))
    return RigRecording(cameras, pattern, traj, duration, seed, **render)
