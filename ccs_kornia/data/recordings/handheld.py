"""A board waved by hand in front of one camera or a rig: a smooth, seeded 6-dof trajectory, a function of time.

The board's pose in the rig's frame (``x_rig = R(t) x_board + t(t)``) is ``R(t) = R_ref exp(w(t))``, ``t(t) = p(t)``:
its state ``(w, p)`` (a rotation vector about a reference orientation that faces the cameras, and a position) is a
cubic Hermite spline through knots, plus a hand's tremor (a few sinusoids of 1-8 Hz, about a millimetre and a few
tenths of a degree). :func:`sample_handheld_trajectory` draws the knots as a person calibrating does:

* **waypoints** where the board is seen by one of the cameras (drawn in turn): its centre on the ray through a
  point of that image, often near the image's corners and sides (``corner_bias``), at the distance where it spans
  ``fill`` of the image's width, tilted by up to ``max_tilt_deg`` about an axis in its plane and turned by up to
  ``max_roll_deg`` about its normal; at least ``min_visible`` of its corners inside that image;
* **sweeps** between them at a peak speed drawn log-uniformly from ``speed`` (metres per second: a few cm/s to about
  1 m/s), turning at most ``max_turn_deg_s``;
* **dwells** at a waypoint (probability ``dwell_prob``, ``dwell`` seconds, drifting slowly); a waypoint without a
  dwell is passed through without stopping (Catmull-Rom velocity).

Example:
    >>> import torch
    >>> from ccs_kornia.data.recordings.patterns import ChessPattern
    >>> from ccs_kornia.data.recordings.recording_camera import RecordingCamera
    >>> cam = RecordingCamera(torch.tensor([[600.0, 0, 319.5], [0, 600, 239.5], [0, 0, 1]]), (640, 480))
    >>> traj = sample_handheld_trajectory([cam], ChessPattern(9, 6, 0.03), duration=5.0, seed=0)
    >>> R, t = traj.pose_at(torch.tensor([0.0, 2.5]))
    >>> R.shape, t.shape, traj.duration >= 5.0
    (torch.Size([2, 3, 3]), torch.Size([2, 3]), True)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from ccs_kornia.data.recordings.patterns import BoardPattern
from ccs_kornia.data.recordings.recording_camera import RecordingCamera
from ccs_kornia.geometry.so3 import exp_so3, log_so3

__all__ = ["BoardTrajectory", "sample_handheld_trajectory"]


@dataclass(eq=False)
class BoardTrajectory:
    """A board's pose as a smooth function of time (see the module docstring).

    Attributes:
        times: :math:`(M,)` knot times (s), increasing.
        state: :math:`(M, 6)` knot states ``(w, p)``: rotation vector about ``reference`` and position.
        velocity: :math:`(M, 6)` the state's time derivative at the knots.
        reference: :math:`(3, 3)` the orientation ``w = 0`` stands for.
        tremor_freq: :math:`(S,)` tremor frequencies (Hz).
        tremor_amp: :math:`(S, 6)` amplitudes (rad, m) per sinusoid and state component.
        tremor_phase: :math:`(S, 6)` phases (rad).
    """

    times: Tensor
    state: Tensor
    velocity: Tensor
    reference: Tensor
    tremor_freq: Tensor
    tremor_amp: Tensor
    tremor_phase: Tensor

    @property
    def duration(self) -> float:
        """The last knot's time: the trajectory is defined on ``[0, duration]`` (held still beyond)."""
        return float(self.times[-1])

    def state_at(self, t: Tensor) -> Tensor:
        """The state ``(w, p)`` at times ``t`` (any shape, s): :math:`(*t.shape, 6)` float64."""
        t = torch.as_tensor(t, dtype=torch.float64)
        flat = t.reshape(-1).clamp(float(self.times[0]), float(self.times[-1]))
        i = (torch.searchsorted(self.times, flat, right=True) - 1).clamp(0, self.times.numel() - 2)
        t0, t1 = self.times[i], self.times[i + 1]
        h = (t1 - t0).clamp_min(1e-12)
        s = ((flat - t0) / h).unsqueeze(-1)
        s2, s3 = s * s, s * s * s
        h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, 3 * s2 - 2 * s3, s3 - s2
        hh = h.unsqueeze(-1)
        x = h00 * self.state[i] + h10 * hh * self.velocity[i] + h01 * self.state[i + 1] + h11 * hh * self.velocity[i + 1]
        phase = 2 * math.pi * flat[:, None, None] * self.tremor_freq[None, :, None] + self.tremor_phase[None]
        x = x + (self.tremor_amp[None] * torch.sin(phase)).sum(1)
        return x.view(*t.shape, 6)

    def pose_at(self, t: Tensor) -> tuple[Tensor, Tensor]:
        """The board's pose in the rig at times ``t``: ``R`` :math:`(*t.shape, 3, 3)`, ``t`` :math:`(*t.shape, 3)`."""
        x = self.state_at(t)
        return self.reference @ exp_so3(x[..., :3]), x[..., 3:]

    @classmethod
    def uniform(cls, R: Tensor, t: Tensor, duration: float, angular=(0.0, 0.0, 0.0),
                linear=(0.0, 0.0, 0.0)) -> BoardTrajectory:
        """A board in uniform motion without tremor: at pose ``(R, t)`` at time 0, turning at ``angular`` (rad/s,
        about its own axes) and moving at ``linear`` (m/s); still by default.

        Example:
            >>> traj = BoardTrajectory.uniform(torch.eye(3), torch.tensor([0.0, 0, 1]), 2.0, linear=(0.5, 0, 0))
            >>> traj.pose_at(torch.tensor(1.0))[1].tolist()
            [0.5, 0.0, 1.0]
        """
        R = torch.as_tensor(R, dtype=torch.float64)
        x0 = torch.cat([torch.zeros(3, dtype=torch.float64), torch.as_tensor(t, dtype=torch.float64)])
        v = torch.cat([torch.as_tensor(angular, dtype=torch.float64), torch.as_tensor(linear, dtype=torch.float64)])
        times = torch.tensor([0.0, float(duration)], dtype=torch.float64)
        none = torch.zeros(1, 6, dtype=torch.float64)
        return cls(times, torch.stack([x0, x0 + v * float(duration)]), torch.stack([v, v]), R,
                   torch.ones(1, dtype=torch.float64), none, none.clone())

    def to_json(self) -> dict:
        """The trajectory as JSON (:meth:`from_json` reads it back; the pose at any time can be recomputed)."""
        return {k: getattr(self, k).tolist() for k in self.__dataclass_fields__}

    @classmethod
    def from_json(cls, data: dict) -> BoardTrajectory:
        """The trajectory written by :meth:`to_json`."""
        return cls(**{k: torch.tensor(data[k], dtype=torch.float64) for k in cls.__dataclass_fields__})


def _facing_reference(cameras: Sequence[RecordingCamera]) -> Tensor:
    """The orientation whose board faces the cameras' mean viewing direction (``z`` along it) in the rig."""
    axes = torch.stack([c.R[2] for c in cameras])  # each camera's optical axis in the rig frame
    d = torch.nn.functional.normalize(axes.mean(0), dim=0)
    z = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    axis = torch.linalg.cross(z, d)
    s = axis.norm()
    if float(s) < 1e-12:
        return torch.eye(3, dtype=torch.float64)
    return exp_so3(axis / s * torch.atan2(s, d[2]))


def _uniform(g: torch.Generator, lo: float, hi: float, n: int = 1) -> Tensor:
    return lo + (hi - lo) * torch.rand(n, generator=g, dtype=torch.float64)


def _waypoint(cam: RecordingCamera, pattern: BoardPattern, g: torch.Generator, fill, corner_bias: float,
              max_tilt_deg: float, max_roll_deg: float, min_visible: float, tries: int = 60) -> tuple[Tensor, Tensor]:
    """One pose of the board (board -> rig) seen by ``cam``; raises when none is found."""
    w, h = cam.image_size
    obj = pattern.object_points()
    centre = pattern.centre
    fx = float(cam.K[0, 0])
    for _ in range(tries):
        f = float(_uniform(g, *fill))
        z = fx * pattern.size / (f * w)
        half = 0.5 * f * w * float(_uniform(g, 0.5, 1.1))  # half the board's width in pixels, roughly
        if float(torch.rand(1, generator=g)) < corner_bias:
            corner = torch.randint(0, 4, (1,), generator=g).item()
            side_x, side_y = corner % 2, corner // 2
            # toward a corner, or along a side when one coordinate is drawn freely
            free = torch.rand(1, generator=g).item()
            x = half if side_x == 0 else w - 1 - half
            y = half * h / w if side_y == 0 else h - 1 - half * h / w
            if free < 0.25:
                x = float(_uniform(g, 0.2 * w, 0.8 * w))
            elif free < 0.5:
                y = float(_uniform(g, 0.2 * h, 0.8 * h))
        else:
            x, y = float(_uniform(g, 0.25 * w, 0.75 * w)), float(_uniform(g, 0.25 * h, 0.75 * h))
        ray = cam.lens.unproject(torch.tensor([[x, y]], dtype=torch.float64), cam.K)[0]
        ray = ray / ray[2].clamp_min(1e-3)
        roll = math.radians(max_roll_deg) * float(_uniform(g, -1.0, 1.0))
        tilt = math.radians(max_tilt_deg) * math.sqrt(float(torch.rand(1, generator=g, dtype=torch.float64)))
        azim = float(_uniform(g, 0.0, 2 * math.pi))
        r_roll = exp_so3(torch.tensor([0.0, 0.0, roll], dtype=torch.float64))
        r_tilt = exp_so3(torch.tensor([math.cos(azim), math.sin(azim), 0.0], dtype=torch.float64) * tilt)
        R_cam = r_tilt @ r_roll @ pattern.upright
        t_cam = z * ray - R_cam @ centre
        pix, ok = cam.project((obj @ R_cam.T + t_cam)[None])
        inside = ok[0] & (pix[0, :, 0] >= 0) & (pix[0, :, 0] <= w - 1) & (pix[0, :, 1] >= 0) & (pix[0, :, 1] <= h - 1)
        if float(inside.double().mean()) >= min_visible:
            R_rig = cam.R.T @ R_cam
            return R_rig, cam.R.T @ (t_cam - cam.T)
    raise RuntimeError("no pose of the board found in the camera's view; is the board far too large for the image?")


def sample_handheld_trajectory(
    cameras: Sequence[RecordingCamera],
    pattern: BoardPattern,
    duration: float = 60.0,
    seed: int = 0,
    fill: tuple[float, float] = (0.2, 0.6),
    corner_bias: float = 0.5,
    max_tilt_deg: float = 50.0,
    max_roll_deg: float = 30.0,
    min_visible: float = 0.6,
    speed: tuple[float, float] = (0.05, 1.0),
    max_turn_deg_s: float = 120.0,
    dwell_prob: float = 0.5,
    dwell: tuple[float, float] = (0.3, 2.0),
    tremor_mm: float = 1.0,
    tremor_deg: float = 0.3,
) -> BoardTrajectory:
    """A hand-held board's trajectory of at least ``duration`` seconds (see the module docstring).

    Args:
        cameras: the cameras the board is shown to (waypoints visit them in random order).
        pattern: the board (its size sets the distances).
        duration: seconds to cover.
        seed: fixes everything.
        fill: the board's width over the image's width at waypoints (range).
        corner_bias: probability that a waypoint lies toward an image corner or side.
        max_tilt_deg, max_roll_deg: tilt about an axis in the board's plane, turn about its normal.
        min_visible: fraction of the corners a waypoint keeps inside its camera's image.
        speed: range of the sweeps' peak speeds (m/s, drawn log-uniformly).
        max_turn_deg_s: the sweeps' largest mean angular speed.
        dwell_prob, dwell: probability and range of the seconds the board rests at a waypoint.
        tremor_mm, tremor_deg: size of the hand's tremor.

    Returns:
        :class:`BoardTrajectory`.
    """
    if not cameras:
        raise ValueError("sample_handheld_trajectory needs at least one camera.")
    if not duration > 0 or not 0 < fill[0] <= fill[1] or not 0 < speed[0] <= speed[1]:
        raise ValueError(f"need duration > 0 and increasing positive fill and speed ranges; got {duration}, {fill}, "
                         f"{speed}.")
    g = torch.Generator().manual_seed(int(seed))
    ref = _facing_reference(cameras)

    def state(R: Tensor, t: Tensor) -> Tensor:
        return torch.cat([log_so3(ref.T @ R), t])

    def waypoint() -> Tensor:
        cam = cameras[int(torch.randint(0, len(cameras), (1,), generator=g))]
        return state(*_waypoint(cam, pattern, g, fill, corner_bias, max_tilt_deg, max_roll_deg, min_visible))

    def drift(x: Tensor) -> Tensor:
        dx = torch.cat([torch.randn(3, generator=g, dtype=torch.float64) * math.radians(1.5),
                        torch.randn(3, generator=g, dtype=torch.float64) * 0.005])
        return x + dx

    # the board starts at rest at a waypoint; each sweep ends at rest (a dwell follows) or passes through
    times, states, still = [0.0], [waypoint()], [True]
    t = float(_uniform(g, *dwell))
    times.append(t)
    states.append(drift(states[-1]))
    still.append(True)
    while t < duration:
        nxt = waypoint()
        dist = float((nxt[3:] - states[-1][3:]).norm())
        turn = math.degrees(float((nxt[:3] - states[-1][:3]).norm()))
        v = math.exp(float(_uniform(g, math.log(speed[0]), math.log(speed[1]))))
        # a cubic Hermite segment from rest to rest peaks at 1.5 times its mean speed
        t += max(1.5 * dist / v, turn / max_turn_deg_s, 0.25)
        rest = float(torch.rand(1, generator=g)) < dwell_prob
        times.append(t)
        states.append(nxt)
        still.append(rest)
        if rest:
            t += float(_uniform(g, *dwell))
            times.append(t)
            states.append(drift(nxt))
            still.append(True)
    times_t = torch.tensor(times, dtype=torch.float64)
    x = torch.stack(states)
    vel = torch.zeros_like(x)
    for i in range(1, len(times) - 1):  # the last knot comes to rest
        if not still[i]:  # passed through: Catmull-Rom, the neighbours' secant
            vel[i] = (x[i + 1] - x[i - 1]) / (times_t[i + 1] - times_t[i - 1])
    s = 3
    freq = _uniform(g, 1.0, 8.0, s)
    amp = torch.cat([torch.full((s, 3), math.radians(tremor_deg)), torch.full((s, 3), tremor_mm * 1e-3)], -1)
    amp = amp * torch.rand(s, 6, generator=g, dtype=torch.float64) / math.sqrt(s)
    phase = _uniform(g, 0.0, 2 * math.pi, s * 6).view(s, 6)
    return BoardTrajectory(times_t, x, vel, ref, freq, amp, phase)
