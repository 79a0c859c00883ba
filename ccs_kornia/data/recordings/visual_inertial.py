r"""Rendered visual-inertial recordings: a hand-held camera (or rig) with an IMU on it, filming a board, with exact
ground truth: the IMU's pose, angular velocity and acceleration at any time, its measurements with white noise and
random-walk biases, and each camera's corner observations at its frame times.

The motion is smooth and analytic (sums of sinusoids in position and orientation, 0.15 - 1.6 Hz, so it is *not* a
B-spline: a fit must approximate it as it would a real hand), swinging the camera about all three axes and moving it
along all three, as Kalibr's guides ask of a calibration recording; its derivatives come from forward-mode
differentiation, so the gyroscope's and accelerometer's truth are exact. Conventions: the world is the board's frame
(board points at ``z = 0``), ``T_cam_imu`` maps IMU-frame points into a camera's frame, and a frame stamped ``t_cam``
by the camera was exposed at IMU time ``t_cam + shift`` (Kalibr's ``timeshift_cam_imu``); a rolling-shutter camera
exposes row ``v`` ``line_delay * v`` later than row 0.

Example:
    >>> rec = visual_inertial_recording(duration=2.0, seed=0)
    >>> rec.gyro.shape, rec.corners[0].shape[-1], rec.frame_times[0].shape
    (torch.Size([400, 3]), 2, torch.Size([30]))
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import torch
from torch import Tensor

from ccs_kornia.geometry.board_warp import warped_board
from ccs_kornia.geometry.camera import OPENCV5, Camera
from ccs_kornia.geometry.imu_intrinsics import ImuIntrinsics
from ccs_kornia.geometry.imu_noise import ImuNoise
from ccs_kornia.geometry.so3 import exp_so3

__all__ = ["HandheldMotion", "VisualInertialRecording", "visual_inertial_recording"]

#: standard gravity (m/s^2)
GRAVITY = 9.80665


def _sinusoids(g: torch.Generator, n: int, amplitude: float, lo: float = 0.15, hi: float = 1.6):
    """``n`` random sinusoids per axis: amplitudes (3, n) (summing to about ``amplitude``), frequencies, phases."""
    a = torch.rand(3, n, generator=g, dtype=torch.float64) + 0.5
    a = a / a.sum(-1, keepdim=True) * amplitude
    f = lo + (hi - lo) * torch.rand(3, n, generator=g, dtype=torch.float64)
    ph = 2 * math.pi * torch.rand(3, n, generator=g, dtype=torch.float64)
    return a, f, ph


def _wave(t: Tensor, a: Tensor, f: Tensor, ph: Tensor) -> Tensor:
    """:math:`(N, 3)` sums of sinusoids at times ``t`` :math:`(N,)`."""
    return (a * torch.sin(2 * math.pi * f * t[:, None, None] + ph)).sum(-1)


@dataclass
class HandheldMotion:
    """A camera swung by hand in front of a board, and the IMU on it: analytic, with exact derivatives.

    Attributes:
        centre: :math:`(3,)` the camera's mean position (board frame).
        base: :math:`(3, 3)` the camera's mean orientation (camera to board), looking at the board.
        position: the sinusoids of the camera's position (amplitudes, frequencies, phases, each (3, n)).
        rotation: the sinusoids of its rotation vector about ``base``.
        R_cam_imu: :math:`(3, 3)`, t_cam_imu: :math:`(3,)`: the IMU in the (first) camera's frame.
    """

    centre: Tensor
    base: Tensor
    position: tuple[Tensor, Tensor, Tensor]
    rotation: tuple[Tensor, Tensor, Tensor]
    R_cam_imu: Tensor
    t_cam_imu: Tensor

    def camera_pose(self, t: Tensor) -> tuple[Tensor, Tensor]:
        """The camera's orientation (camera to board) :math:`(N, 3, 3)` and position :math:`(N, 3)` at times ``t``."""
        return self.base @ exp_so3(_wave(t, *self.rotation)), self.centre + _wave(t, *self.position)

    def imu_pose(self, t: Tensor) -> tuple[Tensor, Tensor]:
        """The IMU's orientation (IMU to board) :math:`(N, 3, 3)` and position :math:`(N, 3)` at times ``t``:
        ``T_board_imu = T_board_cam T_cam_imu``."""
        R, p = self.camera_pose(t)
        return R @ self.R_cam_imu, p + R @ self.t_cam_imu

    def angular_velocity(self, t: Tensor) -> Tensor:
        """The IMU's body-frame angular velocity :math:`(N, 3)` (rad/s): ``R^T dR/dt = [w]_x``."""
        R, dR = torch.func.jvp(lambda s: self.imu_pose(s)[0], (t,), (torch.ones_like(t),))
        S = R.transpose(-1, -2) @ dR
        return torch.stack([S[..., 2, 1] - S[..., 1, 2], S[..., 0, 2] - S[..., 2, 0], S[..., 1, 0] - S[..., 0, 1]], -1) / 2

    def acceleration(self, t: Tensor) -> Tensor:
        """The IMU's acceleration :math:`(N, 3)` in the board's frame (m/s^2)."""
        one = torch.ones_like(t)

        def velocity(s):
            return torch.func.jvp(lambda x: self.imu_pose(x)[1], (s,), (one,))[1]

        return torch.func.jvp(velocity, (t,), (one,))[1]


def _look_at(eye: Tensor, target: Tensor, up: Tensor) -> Tensor:
    """The rotation (camera to world) of a camera at ``eye`` looking at ``target`` (z forward, y down)."""
    z = torch.nn.functional.normalize(target - eye, dim=-1)
    x = torch.nn.functional.normalize(torch.linalg.cross(z, up), dim=-1)
    y = torch.linalg.cross(z, x)
    return torch.stack([x, y, z], -1)


@dataclass
class VisualInertialRecording:
    """A rendered recording of C cameras and one IMU (all float64; see the module doc for the conventions).

    Attributes:
        imu_times: :math:`(N,)` the IMU's sample times (s, its own clock: the reference).
        gyro: :math:`(N, 3)` rad/s. accel: :math:`(N, 3)` m/s^2 (specific force, gravity included).
        cameras: the C cameras' intrinsics (:class:`~ccs_kornia.geometry.camera.Camera`).
        object_points: :math:`(P, 3)` the board's points.
        frame_times: per camera :math:`(F_c,)` the frames' timestamps on the camera's clock.
        corners: per camera :math:`(F_c, P, 2)` the observed points (NaN where not seen).
        T_cam_imu: :math:`(C, 4, 4)` the truth. shift: :math:`(C,)` ``timeshift_cam_imu`` (s), the truth.
        line_delay: :math:`(C,)` a rolling shutter's row delay (s; 0: global shutter).
        gravity: :math:`(3,)` in the board's frame. gyro_bias, accel_bias: :math:`(N, 3)` the biases' truth.
        noise: the IMU's noise densities. pixel_noise: the corners' noise (px, per coordinate).
        imu_intrinsics: how the IMU reads the truth (ideal unless given).
        motion: the analytic motion.
    """

    imu_times: Tensor
    gyro: Tensor
    accel: Tensor
    cameras: Camera
    object_points: Tensor
    frame_times: list[Tensor]
    corners: list[Tensor]
    T_cam_imu: Tensor
    shift: Tensor
    line_delay: Tensor
    gravity: Tensor
    gyro_bias: Tensor
    accel_bias: Tensor
    noise: ImuNoise
    pixel_noise: float
    motion: HandheldMotion = field(repr=False)
    imu_intrinsics: ImuIntrinsics = field(default_factory=ImuIntrinsics.identity)


def _random_rotation(g: torch.Generator) -> Tensor:
    q = torch.nn.functional.normalize(torch.randn(4, generator=g, dtype=torch.float64), dim=0)
    w, x, y, z = q.tolist()
    return torch.tensor([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                         [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                         [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]], dtype=torch.float64)


def _observe(motion: HandheldMotion, camera: Camera, R_c_c0: Tensor, t_c_c0: Tensor, points: Tensor, times: Tensor,
             line_delay: float, noise: float, g: torch.Generator) -> Tensor:
    """The board's points seen by a camera (the rig's camera ``c``: ``x_c = R_c_c0 x_c0 + t_c_c0``) exposed at IMU
    times ``times`` (row 0), with the rolling shutter's row delay: :math:`(F, P, 2)`, NaN where not seen."""
    W, H = camera.image_size

    def project(t):  # t: (F, P)
        R, p = motion.camera_pose(t.flatten())
        R = R.view(*t.shape, 3, 3)
        p = p.view(*t.shape, 3)
        xc0 = (R.transpose(-1, -2) @ (points - p)[..., None])[..., 0]
        xc = (R_c_c0 @ xc0[..., None])[..., 0] + t_c_c0
        uv = camera.project(xc.reshape(1, -1, 3))[0].view(*t.shape, 2)
        return uv, xc

    t = times[:, None].expand(-1, points.shape[0])
    uv, xc = project(t)
    for _ in range(3 if line_delay else 0):  # each point at its own row's time
        uv, xc = project(times[:, None] + line_delay * uv[..., 1].clamp(0, H - 1))
    uv = uv + noise * torch.randn(uv.shape, generator=g, dtype=uv.dtype)
    seen = (xc[..., 2] > 0.05) & (uv[..., 0] >= 0) & (uv[..., 0] <= W - 1) & (uv[..., 1] >= 0) & (uv[..., 1] <= H - 1)
    return uv.masked_fill(~seen[..., None], float("nan"))


def visual_inertial_recording(
    duration: float = 60.0,
    seed: int = 0,
    num_cameras: int = 1,
    fps: float = 20.0,
    imu_rate: float = 200.0,
    shift: float | None = None,
    line_delay: float = 0.0,
    noise: ImuNoise | None = None,
    pixel_noise: float = 0.2,
    board: tuple[int, int] = (7, 6),
    spacing: float = 0.08,
    rotation_amplitude: float = 0.5,
    translation_amplitude: float = 0.2,
    imu_intrinsics: ImuIntrinsics | None = None,
    board_warp: tuple[float, float] | None = None,
) -> VisualInertialRecording:
    """A seeded visual-inertial recording (see the module doc).

    Args:
        duration: seconds of IMU data (the camera frames start and end 0.25 s inside them).
        seed: fixes everything drawn.
        num_cameras: 1, or a stereo rig (2; the second 11 cm to the right) and more.
        fps: the cameras' frame rate. imu_rate: the IMU's (Hz).
        shift: every camera's ``timeshift_cam_imu`` (s); default drawn in -30 .. 30 ms per camera.
        line_delay: a rolling shutter's row delay (s; 0: global shutter).
        noise: the IMU's noise (default EuRoC's; its ``update_rate`` is not used: ``imu_rate`` is). pixel_noise: the corners' (px).
        board: the board's points (columns, rows). spacing: their spacing (m).
        rotation_amplitude: the camera's swing about each axis (rad). translation_amplitude: its motion (m).
        imu_intrinsics: the IMU's scale factors, misalignment and g-sensitivity
            (:class:`~ccs_kornia.geometry.imu_intrinsics.ImuIntrinsics`); default an ideal IMU.
        board_warp: the board's sag ``(c_x, c_y)`` (m, mrcal's ``calobject_warp``,
            :mod:`~ccs_kornia.geometry.board_warp`): the cameras see the bent board, ``object_points`` stay the flat
            one; default a flat board.

    Returns:
        :class:`VisualInertialRecording`.
    """
    g = torch.Generator().manual_seed(int(seed))
    noise = noise or replace(ImuNoise.euroc(), update_rate=imu_rate)
    f64 = torch.float64
    cols, rows = board
    jj, ii = torch.meshgrid(torch.arange(rows, dtype=f64), torch.arange(cols, dtype=f64), indexing="ij")
    points = torch.stack([ii.flatten() * spacing, jj.flatten() * spacing, torch.zeros(cols * rows, dtype=f64)], -1)
    target = torch.tensor([(cols - 1) * spacing / 2, (rows - 1) * spacing / 2, 0.0], dtype=f64)
    distance = 0.55 + 0.2 * float(torch.rand((), generator=g, dtype=f64))
    eye = target + torch.tensor([0.0, 0.0, -distance], dtype=f64)
    base = _look_at(eye, target, torch.tensor([0.0, -1.0, 0.0], dtype=f64))
    R_ci = _random_rotation(g)
    t_ci = (torch.rand(3, generator=g, dtype=f64) - 0.5) * 0.2
    motion = HandheldMotion(centre=eye, base=base, position=_sinusoids(g, 4, translation_amplitude),
                            rotation=_sinusoids(g, 4, rotation_amplitude), R_cam_imu=R_ci, t_cam_imu=t_ci)
    # gravity: the board on a wall or tilted towards the camera
    tilt = exp_so3((torch.rand(3, generator=g, dtype=f64) - 0.5) * 1.0)
    gravity = tilt @ torch.tensor([0.0, GRAVITY, 0.0], dtype=f64)

    n = round(duration * imu_rate)
    t_imu = torch.arange(n, dtype=f64) / imu_rate
    dt = 1.0 / imu_rate
    R_wi, _ = motion.imu_pose(t_imu)
    w_true = motion.angular_velocity(t_imu)
    a_true = (R_wi.transpose(-1, -2) @ (motion.acceleration(t_imu) - gravity)[..., None])[..., 0]

    def walk(initial: float, density: float) -> Tensor:
        steps = torch.randn(n, 3, generator=g, dtype=f64) * density * math.sqrt(dt)
        return initial * (torch.rand(3, generator=g, dtype=f64) - 0.5) * 2 + steps.cumsum(0)

    bg, ba = walk(0.01, noise.gyroscope_random_walk), walk(0.1, noise.accelerometer_random_walk)
    imu = imu_intrinsics or ImuIntrinsics.identity()
    w_true, a_true = imu.apply(w_true, a_true)
    gyro = w_true + bg + torch.randn(n, 3, generator=g, dtype=f64) * noise.gyroscope_noise_density / math.sqrt(dt)
    accel = a_true + ba + torch.randn(n, 3, generator=g, dtype=f64) * noise.accelerometer_noise_density / math.sqrt(dt)

    # cameras: EuRoC's cam0 (752x480, radial-tangential); a rig's others to its right
    K = torch.tensor([[458.654, 0.0, 367.215], [0.0, 457.296, 248.375], [0.0, 0.0, 1.0]], dtype=f64)
    dist = torch.tensor([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0], dtype=f64)
    cams = Camera.from_opencv(OPENCV5, K.expand(num_cameras, 3, 3), dist.expand(num_cameras, 5),
                              image_size=[(752, 480)] * num_cameras)
    seen_points = points if board_warp is None else warped_board(points, torch.tensor(board_warp, dtype=f64))
    T = []
    times, corners, shifts = [], [], []
    for c in range(num_cameras):
        R_c_c0 = exp_so3(torch.tensor([0.0, 0.02 * c, 0.0], dtype=f64))
        t_c_c0 = torch.tensor([-0.11 * c, 0.0, 0.0], dtype=f64)
        s = float(shift) if shift is not None else float((torch.rand((), generator=g, dtype=f64) - 0.5) * 0.06)
        phase = float(torch.rand((), generator=g, dtype=f64)) / fps
        t_cam = torch.arange(0.25 + phase, duration - 0.25, 1.0 / fps, dtype=f64)
        obs = _observe(motion, cams[c], R_c_c0, t_c_c0, seen_points, t_cam + s, line_delay, pixel_noise, g)
        Tc = torch.eye(4, dtype=f64)
        Tc[:3, :3], Tc[:3, 3] = R_c_c0 @ R_ci, R_c_c0 @ t_ci + t_c_c0
        T.append(Tc)
        times.append(t_cam)
        corners.append(obs)
        shifts.append(s)
    return VisualInertialRecording(
        imu_times=t_imu, gyro=gyro, accel=accel, cameras=cams, object_points=points, frame_times=times,
        corners=corners, T_cam_imu=torch.stack(T), shift=torch.tensor(shifts, dtype=f64),
        line_delay=torch.full((num_cameras,), float(line_delay), dtype=f64), gravity=gravity, gyro_bias=bg,
        accel_bias=ba, noise=noise, pixel_noise=pixel_noise, motion=motion, imu_intrinsics=imu)
