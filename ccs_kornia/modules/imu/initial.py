r"""The camera-IMU fit's start: each frame's board pose, the time offset and the rotation between a camera and the IMU
from their angular rates, gravity from the accelerometer, and the IMU's trajectory as a spline through the frames.

* Each camera's board poses: its corners with the camera held (:func:`~ccs_kornia.modules.calibration.board_poses.camera_poses`).
* Time offset: a camera's angular speed between consecutive frames against the gyroscope's, shifted over
  ``-max_shift .. max_shift`` (the speed does not depend on the unknown rotation between the sensors); the shift of the
  highest correlation, refined by a parabola through its neighbours. The correlation curve is kept: its peak's
  sharpness and position (at the search's edge) feed the verdict.
* Clocks from different origins (:func:`clock_offset`, on request): the same speeds cross-correlated over every offset
  at which the recordings overlap, on a 10 ms grid, before the search above.
* Rotation: the camera's rates are the IMU's rotated, ``w_cam = R_cam_imu (w_imu - b_g)``: Kabsch's solution on the
  aligned rates (with the gyroscope's bias as their mean difference).
* Trajectory: the IMU's orientation at each frame (``R_board_cam R_cam_imu``) interpolated at the knots; its position
  the camera's (the lever arm starts at 0, as Kalibr's), fitted in least squares.
* Gravity: ``p'' - R f`` averaged over the recording (``f`` the accelerometer's specific force), 9.80665 m/s^2 long.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ccs_kornia.geometry.so3 import exp_so3, log_so3
from ccs_kornia.geometry.spline import fit_r3_spline, r3_spline, segment_of
from ccs_kornia.modules.calibration.board_poses import camera_poses
from ccs_kornia.modules.imu.problem import ImuCameraData

__all__ = ["GRAVITY", "RateAlignment", "align_rates", "board_poses", "clock_offset", "initial_unknowns"]

#: standard gravity (m/s^2)
GRAVITY = 9.80665


def board_poses(data: ImuCameraData) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Each frame's camera-from-board pose :math:`(F, 3, 3)`, :math:`(F, 3)` and whether it was found :math:`(F,)`."""
    F = data.frame_times.shape[0]
    R = torch.eye(3, dtype=data.gyro.dtype).repeat(F, 1, 1)
    t = data.gyro.new_zeros(F, 3)
    ok = torch.zeros(F, dtype=torch.bool)
    for c in range(data.num_cameras):
        sel = data.frame_camera == c
        if not bool(sel.any()):
            continue
        cam = data.cameras[c]
        rvec, tvec, okc, _ = camera_poses(cam.params.to(data.gyro.dtype), cam.model, data.corners[sel][None],
                                          data.seen[sel][None], data.object_points)
        R[sel], t[sel], ok[sel] = exp_so3(rvec[0]), tvec[0], okc[0]
    return R, t, ok


@dataclass
class RateAlignment:
    """A camera's rates aligned with the gyroscope's.

    Attributes:
        shift: ``timeshift_cam_imu`` (s). R_cam_imu: :math:`(3, 3)`. gyro_bias: :math:`(3,)`.
        shifts: :math:`(S,)` the shifts tried; correlation: :math:`(S,)` the angular speeds' correlation at each.
        rms: the aligned rates' RMS difference (rad/s).
        at_edge: the highest correlation is at the search's edge: the offset may lie beyond it.
    """

    shift: float
    R_cam_imu: torch.Tensor
    gyro_bias: torch.Tensor
    shifts: torch.Tensor
    correlation: torch.Tensor
    rms: float
    at_edge: bool = False


def _interp(t: torch.Tensor, tq: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """Linear interpolation of samples ``x`` :math:`(N, D)` at times ``t`` :math:`(N,)` (sorted) at ``tq``."""
    i = torch.searchsorted(t, tq).clamp(1, t.shape[0] - 1)
    a = ((tq - t[i - 1]) / (t[i] - t[i - 1])).clamp(0, 1)[:, None]
    return x[i - 1] * (1 - a) + x[i] * a


def align_rates(frame_times: torch.Tensor, R_cam_board: torch.Tensor, ok: torch.Tensor, imu_times: torch.Tensor,
                gyro: torch.Tensor, max_shift: float = 0.2, step: float = 5e-4) -> RateAlignment:
    """The time offset and rotation between a camera and the IMU from their angular rates (see the module doc).

    Args:
        frame_times: :math:`(F,)` the camera's frame times (sorted). R_cam_board: :math:`(F, 3, 3)` its board poses;
            ok: :math:`(F,)` where they were found.
        imu_times: :math:`(N,)`; gyro: :math:`(N, 3)`.
        max_shift: the search's half-width (s). step: its resolution before the parabola (s).

    Returns:
        :class:`RateAlignment`.
    """
    f64 = frame_times.dtype
    pair = ok[:-1] & ok[1:]
    dtf = frame_times[1:] - frame_times[:-1]
    pair = pair & (dtf > 0) & (dtf < 0.2)
    t_mid = (0.5 * (frame_times[1:] + frame_times[:-1]))[pair]
    # the camera's body rate between frames: R_board_cam = R_cam_board^T
    Rbc = R_cam_board.transpose(-1, -2)
    w_cam = (log_so3(Rbc[:-1].transpose(-1, -2) @ Rbc[1:]) / dtf[:, None])[pair]
    if t_mid.shape[0] < 10:
        raise ValueError("too few consecutive frames with the board to align the camera's rates with the IMU's.")
    # the gyroscope averaged over each frame interval (a box filter), so both speeds see the same motion
    cum = torch.cat([gyro.new_zeros(1, 3), torch.cumsum(0.5 * (gyro[1:] + gyro[:-1]) * (imu_times[1:] - imu_times[:-1])[:, None], 0)])
    h = 0.5 * dtf[pair]

    def gyro_mean(s: float) -> torch.Tensor:
        lo, hi = t_mid + s - h, t_mid + s + h
        return (_interp(imu_times, hi, cum) - _interp(imu_times, lo, cum)) / (2 * h)[:, None]

    shifts = torch.arange(-max_shift, max_shift + step / 2, step, dtype=f64)
    inside = (t_mid - max_shift - h > imu_times[0]) & (t_mid + max_shift + h < imu_times[-1])
    if int(inside.sum()) < 10:
        raise ValueError("the camera's frames and the IMU's samples do not overlap in time.")
    sc = w_cam[inside].norm(dim=-1)
    sc = sc - sc.mean()
    corr = []
    for s in shifts.tolist():
        si = gyro_mean(s)[inside].norm(dim=-1)
        si = si - si.mean()
        corr.append(float((sc * si).sum() / (sc.norm() * si.norm()).clamp_min(1e-300)))
    corr = torch.tensor(corr, dtype=f64)
    k = int(corr.argmax())
    best = float(shifts[k])
    if 0 < k < len(shifts) - 1:
        a, b, c = corr[k - 1].item(), corr[k].item(), corr[k + 1].item()
        den = a - 2 * b + c
        if den < 0:
            best += 0.5 * (a - c) / den * step
    wi = gyro_mean(best)[inside]
    wc = w_cam[inside]
    # Kabsch with the bias: w_c = R (w_i - b); centre both, rotate, then the bias from the means
    mi, mc = wi.mean(0), wc.mean(0)
    Hm = (wi - mi).T @ (wc - mc)
    U, _, Vh = torch.linalg.svd(Hm)
    D = torch.eye(3, dtype=f64)
    D[2, 2] = torch.sign(torch.linalg.det(Vh.T @ U.T))
    R = Vh.T @ D @ U.T
    bias = mi - R.T @ mc
    rms = float(((wc - (R @ (wi - bias)[..., None])[..., 0]) ** 2).sum(-1).mean().sqrt())
    return RateAlignment(shift=best, R_cam_imu=R, gyro_bias=bias, shifts=shifts, correlation=corr, rms=rms,
                         at_edge=k <= 1 or k >= len(shifts) - 2)


def _masked_ncc(a: torch.Tensor, b: torch.Tensor, mb: torch.Tensor, min_overlap: int) -> torch.Tensor:
    """Normalised cross-correlation of ``a`` :math:`(A,)` with ``b`` :math:`(B,)` (valid where ``mb``) at every lag
    ``L`` (``b[j]`` against ``a[j + L]``, ``L = -(B - 1) .. A - 1``), over the samples they share; ``-inf`` where they
    share fewer than ``min_overlap``."""
    n = a.shape[0] + b.shape[0] - 1
    size = 1 << (n - 1).bit_length()

    def xcorr(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        full = torch.fft.irfft(torch.fft.rfft(x, size) * torch.fft.rfft(y, size).conj(), size)
        # lags 0 .. A-1 then -(B-1) .. -1, put in order
        return torch.cat([full[size - (b.shape[0] - 1):], full[:a.shape[0]]])

    ma = torch.ones_like(a)
    mb = mb.to(a.dtype)
    bm = b * mb
    count = xcorr(ma, mb).round()
    sa, saa, sb, sbb = xcorr(a, mb), xcorr(a * a, mb), xcorr(ma, bm), xcorr(ma, bm * b)
    num = xcorr(a, bm)
    c = count.clamp_min(1)
    den = ((saa - sa * sa / c) * (sbb - sb * sb / c)).clamp_min(1e-300).sqrt()
    ncc = (num - sa * sb / c) / den
    return torch.where(count >= min_overlap, ncc, torch.full_like(ncc, float("-inf")))


def clock_offset(frame_times: torch.Tensor, R_cam_board: torch.Tensor, ok: torch.Tensor, imu_times: torch.Tensor,
                 gyro: torch.Tensor, step: float = 0.01) -> tuple[float, float]:
    """The offset between a camera's clock and the IMU's when their origins differ (a video's from 0, an IMU log's
    from the epoch): the angular speeds' normalised cross-correlation over every offset at which the two recordings
    share half of the camera's span, on a ``step`` s grid (a coarse value for :func:`align_rates`).

    Returns:
        ``(offset, correlation)``: ``t_imu ~ t_cam + offset`` (s) and the peak's correlation.

    Example:
        >>> from ccs_kornia.data.recordings.visual_inertial import visual_inertial_recording
        >>> from ccs_kornia.modules.imu.problem import ImuCameraData
        >>> r = visual_inertial_recording(duration=12.0, seed=5)
        >>> d = ImuCameraData.from_corners(r.imu_times, r.gyro, r.accel, r.cameras, r.object_points,
        ...                                [r.frame_times[0] - 1000.0], r.corners)  # the camera's clock 1000 s behind
        >>> R, _, ok = board_poses(d)
        >>> offset, _ = clock_offset(d.frame_times, R, ok, d.imu_times, d.gyro)
        >>> abs(offset - (1000.0 + float(r.shift[0]))) < 0.02
        True
    """
    f64 = frame_times.dtype
    pair = ok[:-1] & ok[1:]
    dtf = frame_times[1:] - frame_times[:-1]
    pair = pair & (dtf > 0) & (dtf < 0.2)
    if int(pair.sum()) < 10:
        raise ValueError("too few consecutive frames with the board to align the clocks.")
    t_mid = (0.5 * (frame_times[1:] + frame_times[:-1]))[pair]
    Rbc = R_cam_board.transpose(-1, -2)
    speed_cam = (log_so3(Rbc[:-1].transpose(-1, -2) @ Rbc[1:]) / dtf[:, None])[pair].norm(dim=-1)
    # each sensor's angular speed on its own clock's grid: the camera's where a frame pair is within a step
    grid_c = torch.arange(float(t_mid[0]), float(t_mid[-1]), step, dtype=f64)
    j = torch.searchsorted(t_mid, grid_c).clamp(1, t_mid.shape[0] - 1)
    near = torch.where((grid_c - t_mid[j - 1]).abs() < (grid_c - t_mid[j]).abs(), j - 1, j)
    cam = speed_cam[near]
    cam_ok = (t_mid[near] - grid_c).abs() <= max(step, float(dtf[pair].median()))
    grid_i = torch.arange(float(imu_times[0]), float(imu_times[-1]), step, dtype=f64)
    cum = torch.cat([gyro.new_zeros(1, 3), torch.cumsum(0.5 * (gyro[1:] + gyro[:-1])
                                                        * (imu_times[1:] - imu_times[:-1])[:, None], 0)])
    h = 0.5 * float(dtf[pair].median())
    imu = ((_interp(imu_times, grid_i + h, cum) - _interp(imu_times, grid_i - h, cum)) / (2 * h)).norm(dim=-1)
    ncc = _masked_ncc(imu, cam, cam_ok, min_overlap=max(10, int(0.5 * int(cam_ok.sum()))))
    k = int(ncc.argmax())
    if not torch.isfinite(ncc[k]):
        raise ValueError("the camera's and the IMU's recordings are too short to align their clocks.")
    lag = k - (cam.shape[0] - 1)
    return float(grid_i[0]) + lag * step - float(grid_c[0]), float(ncc[k])


def _slerp_at(times: torch.Tensor, R: torch.Tensor, tq: torch.Tensor) -> torch.Tensor:
    """Rotations :math:`(F, 3, 3)` at sorted ``times`` interpolated geodesically at ``tq`` (held at the ends)."""
    i = torch.searchsorted(times, tq).clamp(1, times.shape[0] - 1)
    a = ((tq - times[i - 1]) / (times[i] - times[i - 1])).clamp(0, 1)[:, None]
    return R[i - 1] @ exp_so3(a * log_so3(R[i - 1].transpose(-1, -2) @ R[i]))


def initial_unknowns(data: ImuCameraData, t0: float, dt: float, num_points: int, R_cam_board: torch.Tensor,
                     t_cam_board: torch.Tensor, ok: torch.Tensor, alignments: list[RateAlignment],
                     reference: int = 0) -> dict[str, torch.Tensor]:
    """The fit's initial unknowns (batch 1) from the board poses and each camera's rate alignment.

    Args:
        data: the measurements. t0, dt, num_points: the spline's knots.
        R_cam_board, t_cam_board, ok: :func:`board_poses`'s.
        alignments: one :class:`RateAlignment` per camera.
        reference: the camera whose frames shape the trajectory.

    Returns:
        the unknowns of :class:`~ccs_kornia.modules.imu.problem.ImuCameraProblem`.
    """
    f64 = data.gyro.dtype
    C = data.num_cameras
    sel = (data.frame_camera == reference) & ok
    al = alignments[reference]
    tau = data.frame_times[sel] + al.shift
    Rbc = R_cam_board[sel].transpose(-1, -2)
    pos = -(Rbc @ t_cam_board[sel][..., None])[..., 0]  # the camera's centre in the board's frame
    R_board_imu = Rbc @ al.R_cam_imu
    # control point k peaks at t0 + (k - 1) dt
    knots = t0 + (torch.arange(num_points, dtype=f64) - 1) * dt
    R_cp = _slerp_at(tau, R_board_imu, knots)
    p_cp = fit_r3_spline(tau, pos, t0, dt, num_points, smoothing=1e-3)
    # gravity: the mean of p'' - R f over the IMU samples inside the frames' span
    inside = (data.imu_times > tau[0]) & (data.imu_times < tau[-1])
    ti = data.imu_times[inside]
    i, u = segment_of(ti, t0, dt, num_points)
    idx = i[:, None] + torch.arange(4)
    acc = r3_spline(p_cp[idx], u, dt, 2)
    R_i = _slerp_at(tau, R_board_imu, ti)
    g = (acc - (R_i @ data.accel[inside][..., None])[..., 0]).mean(0)
    g = torch.nn.functional.normalize(g, dim=0) * GRAVITY
    M = num_points
    return {
        "R": R_cp[None],
        "p": p_cp[None],
        "bg": al.gyro_bias.expand(1, M, 3).clone(),
        "ba": data.gyro.new_zeros(1, M, 3),
        "Rci": torch.stack([a.R_cam_imu for a in alignments])[None],
        "tci": data.gyro.new_zeros(1, C, 3),
        "shift": torch.tensor([[a.shift for a in alignments]], dtype=f64),
        "delay": data.gyro.new_zeros(1, C),
        "params": data.cameras.params.to(f64)[None].clone(),
        # the IMU's intrinsics: ideal (geometry.imu_intrinsics)
        "Tg": torch.eye(3, dtype=f64)[None].clone(),
        "Ta": torch.eye(3, dtype=f64)[None].clone(),
        "Ag": torch.zeros(1, 3, 3, dtype=f64),
        "g": g[None],
        # the board's sag: flat (geometry.board_warp)
        "warp": torch.zeros(1, 2, dtype=f64),
    }
