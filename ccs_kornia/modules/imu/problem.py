r"""The camera-IMU fit's normal equations: a continuous-time trajectory of the IMU, its biases, gravity, and where each
camera sits on it and when its frames were taken, fitted to every gyroscope, accelerometer and corner measurement.

Unknowns (Furgale et al., "Unified temporal and spatial calibration for multi-sensor systems", IROS 2013, as Kalibr):

* per control point ``k`` of a uniform cubic B-spline (:mod:`ccs_kornia.geometry.spline`), the *item* of the LM core:
  the IMU's orientation ``R_k`` (IMU to board; moved by ``R_k exp(d)``) and position ``p_k``, and the gyroscope's and
  accelerometer's biases ``bg_k``, ``ba_k`` (the same B-spline): 12 unknowns; a control point couples its three
  neighbours, so the item blocks are block-banded and a step costs time linear in the recording's length;
* the *global* unknowns: per camera ``T_cam_imu`` (``R <- exp(d) R``, ``t``) and its time shift (a frame stamped
  ``t_cam`` by the camera is seen at IMU time ``t_cam + shift``), for a rolling-shutter camera its row delay (row
  ``v`` is read ``delay * v`` after row 0: each corner is an observation at its own time), and gravity in the board's
  frame (its direction: 2 unknowns; its magnitude held); on request each camera's parameters (its lens model's,
  refined from the same corners); on request the board's sag (mrcal's two coefficients ``c``,
  :mod:`~ccs_kornia.geometry.board_warp`: a board point ``X`` moves along the board's z by ``b(X) . c``, the last two
  globals). A rig's cameras can be held to their calibrated poses in
  camera 0's frame (``rig``): then only camera 0's ``T_cam_imu`` moves and the others follow it. A step of camera 0,
  ``(d, dt)``, moves camera ``c`` (``x_c = R_c0 x_0 + t_c0``) by exactly ``(R_c0 d, R_c0 dt)``, so the held rig is the
  linear map :attr:`ImuCameraProblem.P` from the reduced unknowns to every camera's, applied to the normal equations
  (``P^T U P``, ``P^T W``, ``P^T e``) and to each step.

Residuals, each whitened by its standard deviation: gyroscope ``w(t) + bg(t) - w_meas``; accelerometer
``R(t)^T (p''(t) - g) + ba(t) - a_meas``; every corner ``project(T_cam_imu T_imu_board(t_cam + shift) X) - uv``; the
biases' random walk ``b_{k+1} - b_k`` with variance ``sigma_rw^2 dt``. A corner's derivative by the sag is
``(d uv / d x_cam) R_cam_board e_z b_k(X)``. The orientation's derivatives by its control
points come from forward-mode differentiation of the spline (exact), the rest are written out. Per segment of the
spline the Jacobians touch four control points and the globals, so the normal equations are accumulated per segment
(a dense ``48 + G`` block) and then spread over the banded item blocks.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ccs_kornia.geometry.board_warp import board_warp_basis, warped_board
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.imu_intrinsics import UPPER, ImuModel
from ccs_kornia.geometry.so3 import exp_so3, skew
from ccs_kornia.geometry.spline import segment_of, so3_spline, spline_basis
from ccs_kornia.modules.calibration.schur_lm import NormalEquations

__all__ = ["ITEM", "ImuCameraData", "ImuCameraProblem", "Weights", "gravity_basis"]

#: unknowns per control point: rotation, position, gyroscope bias, accelerometer bias
ITEM = 12
#: samples per chunk when accumulating the IMU's normal equations (bounds the memory of the per-sample blocks)
_CHUNK = 4096


def gravity_basis(g: torch.Tensor) -> torch.Tensor:
    """:math:`(*, 3, 2)` two unit vectors orthogonal to gravity ``g`` :math:`(*, 3)` (its direction's tangent plane).

    Example:
        >>> gravity_basis(torch.tensor([0.0, 0.0, -9.8])).T @ torch.tensor([0.0, 0.0, 1.0])
        tensor([0., 0.])
    """
    n = torch.nn.functional.normalize(g, dim=-1)
    # the axis least aligned with g, made orthogonal to it
    e = torch.eye(3, dtype=g.dtype, device=g.device)[n.abs().argmin(-1)]
    a = torch.nn.functional.normalize(e - (e * n).sum(-1, keepdim=True) * n, dim=-1)
    return torch.stack([a, torch.linalg.cross(n, a)], -1)


@dataclass
class ImuCameraData:
    """The measurements of one recording: one IMU and C cameras (float64).

    Attributes:
        imu_times: :math:`(N,)` s (the reference clock). gyro: :math:`(N, 3)` rad/s. accel: :math:`(N, 3)` m/s^2.
        cameras: the C cameras (held).
        object_points: :math:`(P, 3)` the board's points.
        frame_times: :math:`(F,)` every camera's frames, one after the other (camera clocks).
        frame_camera: :math:`(F,)` int64 the camera of each frame.
        corners: :math:`(F, P, 2)`; seen: :math:`(F, P)` bool.
    """

    imu_times: torch.Tensor
    gyro: torch.Tensor
    accel: torch.Tensor
    cameras: Camera
    object_points: torch.Tensor
    frame_times: torch.Tensor
    frame_camera: torch.Tensor
    corners: torch.Tensor
    seen: torch.Tensor

    @property
    def num_cameras(self) -> int:
        return len(self.cameras)

    @classmethod
    def from_corners(cls, imu_times: torch.Tensor, gyro: torch.Tensor, accel: torch.Tensor, cameras: Camera,
                     object_points: torch.Tensor, frame_times: list[torch.Tensor], corners: list[torch.Tensor],
                     min_corners: int = 6) -> ImuCameraData:
        """The measurements from each camera's frame times :math:`(F_c,)` and corners :math:`(F_c, P, 2)` (NaN where
        not seen); frames with fewer than ``min_corners`` corners are left out.

        Example:
            >>> from ccs_kornia.data.recordings.visual_inertial import visual_inertial_recording
            >>> r = visual_inertial_recording(duration=2.0, seed=0)
            >>> d = ImuCameraData.from_corners(r.imu_times, r.gyro, r.accel, r.cameras, r.object_points,
            ...                                r.frame_times, r.corners)
            >>> d.corners.shape[0] == r.frame_times[0].shape[0], d.num_cameras
            (True, 1)
        """
        f64 = torch.float64
        times, cams, obs = [], [], []
        for c, (t, x) in enumerate(zip(frame_times, corners)):
            seen = x.isfinite().all(-1)
            keep = seen.sum(-1) >= min_corners
            times.append(t[keep].to(f64))
            obs.append(x[keep].to(f64))
            cams.append(torch.full((int(keep.sum()),), c, dtype=torch.long))
        x = torch.cat(obs)
        seen = x.isfinite().all(-1)
        return cls(imu_times=imu_times.to(f64), gyro=gyro.to(f64), accel=accel.to(f64), cameras=cameras,
                   object_points=object_points.to(f64), frame_times=torch.cat(times), frame_camera=torch.cat(cams),
                   corners=x.nan_to_num(0.0), seen=seen)


@dataclass
class _Observations:
    """A batch of corner observations: frames ``frames`` (F,) of the data (and under a rolling shutter the corner
    ``corner`` (F,) of each, alone), their cameras, times on the cameras' clocks (the row's, under a rolling shutter),
    observed rows, board points (F, P, 3) (bent by the state's sag where the problem estimates one), the sag's two
    shapes at them (F, P, 2) (``None``: a flat board), corners (F, P, 2) and which are seen (F, P)."""

    frames: torch.Tensor
    corner: torch.Tensor | None
    camera: torch.Tensor
    times: torch.Tensor
    rows: torch.Tensor | None
    points: torch.Tensor
    sag: torch.Tensor | None
    corners: torch.Tensor
    seen: torch.Tensor


@dataclass
class Weights:
    """Inverse variances of one sample of each measurement."""

    gyro: float
    accel: float
    pixel: float
    gyro_walk: float  #: of a control point's gyroscope-bias step
    accel_walk: float  #: of a control point's accelerometer-bias step


class ImuCameraProblem:
    """The camera-IMU fit as a :class:`~ccs_kornia.modules.calibration.schur_lm.SchurProblem` (one recording, batch 1).

    Args:
        data: the measurements.
        t0, dt, num_points: the spline's knots.
        weights: the measurements' inverse variances (:class:`Weights`).
        rolling_shutter: each camera reads its rows one after the other, ``delay`` s apart (an unknown per camera,
            ``s["delay"]``): a corner is seen at its row's time, ``t_cam + shift + delay * v`` (``v`` its observed row).
        rig: :math:`(C, 4, 4)` each camera's pose in camera 0's frame (``x_c = T_c0 x_0``), held: camera 0's
            ``T_cam_imu`` is fitted and the others follow it (their time shifts and row delays stay their own).
            ``None``: each camera's ``T_cam_imu`` is its own.
        refine_intrinsics: each camera's parameters (``s["params"]``, its model's) are unknowns too, after the time
            shift (and row delay); the cameras must share one model.
        imu_model: :attr:`ImuModel.SCALE_MISALIGNMENT`: the IMU's intrinsics (``s["Tg"]``, ``s["Ta"]``, ``s["Ag"]``,
            :mod:`~ccs_kornia.geometry.imu_intrinsics`) are unknowns, 24 after gravity's; else they are held (ideal).
        board_warp: the board's sag (``s["warp"]`` :math:`(1, 2)`, mrcal's ``calobject_warp``) is an unknown too, the
            last two globals; ``False``: the board is flat (``s["warp"]`` ignored).
    """

    def __init__(self, data: ImuCameraData, t0: float, dt: float, num_points: int, weights: Weights,
                 rolling_shutter: bool = False, rig: torch.Tensor | None = None,
                 refine_intrinsics: bool = False, imu_model: ImuModel = ImuModel.CALIBRATED,
                 board_warp: bool = False) -> None:
        self.data, self.t0, self.dt, self.M, self.w = data, t0, dt, num_points, weights
        C = data.num_cameras
        self.rolling_shutter = rolling_shutter
        if refine_intrinsics and not data.cameras.uniform:
            raise ValueError("the cameras' intrinsics are refined for cameras of one model only.")
        #: the cameras' parameters refined per camera (0: held)
        self.NP = data.cameras.params.shape[1] if refine_intrinsics else 0
        #: where a camera's parameters start among its global unknowns
        self.P0 = 8 if rolling_shutter else 7
        #: global unknowns per camera: rotation, translation, time shift (the row delay, the camera's parameters)
        self.K = self.P0 + self.NP
        #: the IMU's intrinsics estimated (24 unknowns after gravity's: T_g by rows, T_a's upper triangle, A_g by rows)
        self.NI = 24 if imu_model is ImuModel.SCALE_MISALIGNMENT else 0
        #: the board's sag estimated (2 unknowns, the last globals)
        self.NW = 2 if board_warp else 0
        #: the sag's two shapes at the board's points (P, 2), None for a flat board
        self.sag = board_warp_basis(data.object_points) if board_warp else None
        #: every camera's global unknowns, gravity's, the IMU's and the sag's: the Jacobians' layout
        self.G_all = self.K * C + 2 + self.NI + self.NW
        self.L = 4 * ITEM + self.G_all
        dtype, device = data.gyro.dtype, data.gyro.device
        #: (G_all, G) every camera's unknowns from the fitted ones (the identity unless a rig is held)
        self.P = self._held_rig(rig.to(dtype=dtype, device=device)) if rig is not None else None
        self.G = self.P.shape[1] if self.P is not None else self.G_all
        self.imu_seg, self.imu_u = segment_of(data.imu_times, t0, dt, num_points)
        self.used = torch.ones(1, num_points, dtype=torch.bool, device=device)
        n_res = 6 * data.imu_times.shape[0] + 2 * int(data.seen.sum()) + 6 * (num_points - 1)
        self.num_residuals = torch.tensor([n_res], device=device)
        self.floor = torch.full((1,), 1e-30, dtype=dtype, device=device)

    def _held_rig(self, rig: torch.Tensor) -> torch.Tensor:
        """The map from the fitted globals (camera 0's rotation and translation, then each camera's time shift and row
        delay, then gravity's two, the IMU's and the sag's) to every camera's."""
        C, K = self.data.num_cameras, self.K
        T = K - 6  # per camera: the time shift (and the row delay)
        tail = self.G_all - K * C  # gravity's, the IMU's and the sag's unknowns
        P = rig.new_zeros(self.G_all, 6 + T * C + tail)
        for c in range(C):
            R = rig[c, :3, :3]
            P[K * c:K * c + 3, 0:3] = R
            P[K * c + 3:K * c + 6, 3:6] = R
            P[K * c + 6:K * c + K, 6 + T * c:6 + T * (c + 1)] = torch.eye(T, dtype=rig.dtype, device=rig.device)
        P[K * C:, -tail:] = torch.eye(tail, dtype=rig.dtype, device=rig.device)
        return P

    def all_globals(self, dg: torch.Tensor) -> torch.Tensor:
        """:math:`(B, G_{all})` every camera's step (and gravity's) from a step of the fitted globals :math:`(B, G)`."""
        return dg if self.P is None else dg @ self.P.T

    def all_covariance(self, cov: torch.Tensor) -> torch.Tensor:
        """:math:`(G_{all}, G_{all})` the covariance of every camera's globals from the fitted ones' :math:`(G, G)`."""
        return cov if self.P is None else self.P @ cov @ self.P.T

    # -- the LM core's protocol --------------------------------------------------------------------------------------
    def take(self, keep: torch.Tensor) -> ImuCameraProblem:
        if not bool(keep.all()):
            raise ValueError("the camera-IMU problem is one recording: it cannot be split.")
        return self

    def scale(self, s: dict[str, torch.Tensor]) -> torch.Tensor:
        return torch.ones(1, dtype=s["p"].dtype, device=s["p"].device)

    def retract(self, s: dict[str, torch.Tensor], dg: torch.Tensor, dp: torch.Tensor) -> dict[str, torch.Tensor]:
        C, K = self.data.num_cameras, self.K
        dg = self.all_globals(dg)
        cam = dg[:, : K * C].view(1, C, K)
        B = gravity_basis(s["g"])
        return {
            "R": s["R"] @ exp_so3(dp[..., 0:3]),
            "p": s["p"] + dp[..., 3:6],
            "bg": s["bg"] + dp[..., 6:9],
            "ba": s["ba"] + dp[..., 9:12],
            "Rci": exp_so3(cam[..., 0:3]) @ s["Rci"],
            "tci": s["tci"] + cam[..., 3:6],
            "shift": s["shift"] + cam[..., 6],
            "delay": s["delay"] + cam[..., 7] if self.rolling_shutter else s["delay"],
            "params": s["params"] + cam[..., self.P0:] if self.NP else s["params"],
            "g": (exp_so3((B @ dg[:, K * C:K * C + 2, None])[..., 0]) @ s["g"][..., None])[..., 0],
            **self._imu_retract(s, dg[:, K * C + 2:K * C + 2 + self.NI]),
            "warp": s["warp"] + dg[:, self.G_all - 2:] if self.NW else s["warp"],
        }

    def _imu_retract(self, s, d):
        """The IMU's intrinsics moved by their step (held when not estimated)."""
        if not self.NI:
            return {"Tg": s["Tg"], "Ta": s["Ta"], "Ag": s["Ag"]}
        Ta = s["Ta"].clone()
        for k, (i, j) in enumerate(UPPER):
            Ta[:, i, j] = Ta[:, i, j] + d[:, 9 + k]
        return {"Tg": s["Tg"] + d[:, 0:9].view(-1, 3, 3), "Ta": Ta, "Ag": s["Ag"] + d[:, 15:24].view(-1, 3, 3)}

    def linearize(self, s: dict[str, torch.Tensor]) -> NormalEquations:
        H, b, cost = self._segment_blocks(s)
        return self._spread(H, b, cost, s)

    def board(self, s: dict[str, torch.Tensor]) -> torch.Tensor:
        """:math:`(P, 3)` the board's points as the state has them (bent by its sag where the problem estimates one)."""
        return warped_board(self.data.object_points, s["warp"][0] if self.sag is not None else None)

    def residuals(self, s: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The unweighted residuals at ``s``: gyroscope :math:`(N, 3)` rad/s, accelerometer :math:`(N, 3)` m/s^2 and
        corners :math:`(F, P, 2)` px (0 where not seen)."""
        d, dt, _C = self.data, self.dt, self.data.num_cameras
        R, p, bg, ba, g = s["R"][0], s["p"][0], s["bg"][0], s["ba"][0], s["g"][0]
        idx = self.imu_seg[:, None] + torch.arange(4, device=R.device)
        Rt, w = so3_spline(R[idx], self.imu_u, self.dt)
        B0, B2 = spline_basis(self.imu_u), spline_basis(self.imu_u, 2) / dt**2
        acc = (B2[:, None, :] @ p[idx])[:, 0] - g
        f = (Rt.transpose(-1, -2) @ acc[..., None])[..., 0]
        w, f_read = self._readings(s, w, f)
        rg = w + (B0[:, None, :] @ bg[idx])[:, 0] - d.gyro
        ra = f_read + (B0[:, None, :] @ ba[idx])[:, 0] - d.accel
        rc = torch.zeros_like(d.corners)
        for o in self._observations(s):
            R_cb, t_cb = self._poses(s, o)[:2]
            uv = self._project(s, R_cb, t_cb, o)[0]
            r = torch.where(o.seen[..., None], uv - o.corners, 0.0)
            if o.corner is None:
                rc[o.frames] = r
            else:
                rc[o.frames, o.corner] = r[:, 0]
        return rg, ra, rc

    def _observations(self, s):
        """The corners as batches of :class:`_Observations` (frames, or under a rolling shutter each corner alone at
        its row's time), at most :data:`_CHUNK` * 4 at once."""
        d = self.data
        F = d.corners.shape[0]
        board = self.board(s)
        if not self.rolling_shutter:
            for lo in range(0, F, _CHUNK):
                f = torch.arange(lo, min(F, lo + _CHUNK), device=d.corners.device)
                yield _Observations(frames=f, corner=None, camera=d.frame_camera[f], times=d.frame_times[f],
                                    rows=None, points=board.expand(len(f), -1, -1),
                                    sag=None if self.sag is None else self.sag.expand(len(f), -1, -1),
                                    corners=d.corners[f], seen=d.seen[f])
            return
        f_all, n_all = d.seen.nonzero(as_tuple=True)
        for lo in range(0, f_all.shape[0], 4 * _CHUNK):
            f, n = f_all[lo:lo + 4 * _CHUNK], n_all[lo:lo + 4 * _CHUNK]
            cam = d.frame_camera[f]
            v = d.corners[f, n, 1]
            yield _Observations(frames=f, corner=n, camera=cam, times=d.frame_times[f] + s["delay"][0][cam] * v, rows=v,
                                points=board[n][:, None], sag=None if self.sag is None else self.sag[n][:, None],
                                corners=d.corners[f, n][:, None],
                                seen=torch.ones(len(f), 1, dtype=torch.bool, device=f.device))

    def _poses(self, s, o):
        """The cameras' poses (camera from board) at the observations' times, and what their derivatives need."""
        R, p = s["R"][0], s["p"][0]
        tau = o.times + s["shift"][0][o.camera]
        seg, u = segment_of(tau, self.t0, self.dt, self.M)
        idx = seg[:, None] + torch.arange(4, device=R.device)
        Rt, w, E, _ = so3_spline(R[idx], u, self.dt, jacobians=True)
        Bu = spline_basis(u)
        pt = (Bu[:, None, :] @ p[idx])[:, 0]
        vel = (spline_basis(u, 1)[:, None, :] @ p[idx])[:, 0] / self.dt
        R_cb = s["Rci"][0][o.camera] @ Rt.transpose(-1, -2)
        t_cb = s["tci"][0][o.camera] - (R_cb @ pt[..., None])[..., 0]
        return R_cb, t_cb, seg, w, E, Bu, vel

    def cameras(self, s: dict[str, torch.Tensor]) -> Camera:
        """The cameras at ``s`` (their parameters refined, or as given)."""
        return self.data.cameras.with_params(s["params"][0]) if self.NP else self.data.cameras

    def _project(self, s, R_cb, t_cb, o, jacobians: bool = False):
        """The observations' points projected by their cameras (and ``d uv / d x_cam``, ``d uv / d params``)."""
        C = self.data.num_cameras
        F, P = o.points.shape[:2]
        xc = (R_cb[:, None] @ o.points[..., None])[..., 0] + t_cb[:, None]
        res = self.cameras(s).project(xc[None].expand(C, -1, -1, -1), jacobians=jacobians)
        uv, Jp, Jx = res if jacobians else (res, None, None)
        uv = uv.gather(0, o.camera[None, :, None, None].expand(1, F, P, 2))[0]
        if jacobians:
            Jx = Jx.gather(0, o.camera[None, :, None, None, None].expand(1, F, P, 2, 3))[0]
            Jp = Jp.gather(0, o.camera[None, :, None, None, None].expand(1, F, P, 2, Jp.shape[-1]))[0]
        return uv, Jx, xc, Jp

    def _readings(self, s, w, f):
        """The gyroscope's and accelerometer's readings of true rates ``w`` and specific forces ``f`` :math:`(n, 3)`
        (the IMU's intrinsics applied where estimated)."""
        if not self.NI:
            return w, f
        Tg, Ta, Ag = s["Tg"][0], s["Ta"][0], s["Ag"][0]
        return w @ Tg.T + f @ Ag.T, f @ Ta.T

    # -- residuals -------------------------------------------------------------------------------------------------
    def _imu_blocks(self, s, H, b):
        """The gyroscope's and accelerometer's residuals, accumulated into the segment blocks; their cost."""
        d, dt, C = self.data, self.dt, self.data.num_cameras
        R, p, bg, ba, g = s["R"][0], s["p"][0], s["bg"][0], s["ba"][0], s["g"][0]
        gB = gravity_basis(g)
        ar4 = torch.arange(4, device=R.device)
        sg, sa = self.w.gyro**0.5, self.w.accel**0.5
        cost = R.new_zeros(())
        for lo in range(0, d.imu_times.shape[0], _CHUNK):
            sl = slice(lo, lo + _CHUNK)
            seg, u = self.imu_seg[sl], self.imu_u[sl]
            idx = seg[:, None] + ar4
            n = seg.shape[0]
            Rt, w, E, Dw = so3_spline(R[idx], u, dt, jacobians=True)
            B0 = spline_basis(u)  # (n, 4)
            B2 = spline_basis(u, 2) / dt**2
            acc_w = (B2[:, None, :] @ p[idx])[:, 0]
            v = acc_w - g
            Rtv = (Rt.transpose(-1, -2) @ v[..., None])[..., 0]  # the specific force in the IMU's frame
            w_read, f_read = self._readings(s, w, Rtv)
            rg = w_read + (B0[:, None, :] @ bg[idx])[:, 0] - d.gyro[sl]
            ra = f_read + (B0[:, None, :] @ ba[idx])[:, 0] - d.accel[sl]
            J = R.new_zeros(n, 6, self.L)
            eye = torch.eye(3, dtype=R.dtype, device=R.device)
            gi = 4 * ITEM + self.K * C
            # rows 0:3 the true rate's derivatives, rows 3:6 the specific force's (the readings' below)
            for j in range(4):
                o = ITEM * j
                J[:, 0:3, o:o + 3] = Dw[:, j]
                # R <- R exp(E_j delta_j): R^T v <- R^T v + [R^T v]_x E_j delta_j
                J[:, 3:6, o:o + 3] = skew(Rtv) @ E[:, j]
                J[:, 3:6, o + 3:o + 6] = B2[:, j, None, None] * Rt.transpose(-1, -2)
            # d(-R^T g) / d g_delta, with g <- exp(B d) g: dg = -[g]_x B d
            J[:, 3:6, gi:gi + 2] = Rt.transpose(-1, -2) @ (skew(g) @ gB)
            if self.NI:
                Tg, Ta, Ag = s["Tg"][0], s["Ta"][0], s["Ag"][0]
                J = torch.cat([Tg @ J[:, 0:3] + Ag @ J[:, 3:6], Ta @ J[:, 3:6]], 1)
                for i in range(3):
                    J[:, i, gi + 2 + 3 * i:gi + 5 + 3 * i] = w
                    J[:, i, gi + 17 + 3 * i:gi + 20 + 3 * i] = Rtv
                for k, (i, c) in enumerate(UPPER):
                    J[:, 3 + i, gi + 11 + k] = Rtv[:, c]
            for j in range(4):
                o = ITEM * j
                J[:, 0:3, o + 6:o + 9] = B0[:, j, None, None] * eye
                J[:, 3:6, o + 9:o + 12] = B0[:, j, None, None] * eye
            J[:, 0:3] *= sg
            J[:, 3:6] *= sa
            r = torch.cat([rg * sg, ra * sa], -1)
            H.index_add_(0, seg, J.transpose(-1, -2) @ J)
            b.index_add_(0, seg, (J.transpose(-1, -2) @ r[..., None])[..., 0])
            cost = cost + (r * r).sum()
        return cost

    def _frame_blocks(self, s, H, b):
        """The corners' residuals, accumulated into the segment blocks; their cost."""
        d, _C, K = self.data, self.data.num_cameras, self.K
        dtype, device = d.corners.dtype, d.corners.device
        eye = torch.eye(3, dtype=dtype, device=device)
        n_loc = 24 + K + self.NW
        # an observation's local unknowns (4 control rotations, 4 control positions, its camera's, the sag's) in the
        # segment layout
        loc = torch.cat([(ITEM * torch.arange(4)[:, None] + torch.arange(3)).flatten(),
                         (ITEM * torch.arange(4)[:, None] + 3 + torch.arange(3)).flatten()]).to(device)
        cost = torch.zeros((), dtype=dtype, device=device)
        sp = self.w.pixel**0.5
        for o in self._observations(s):
            R_cb, t_cb, seg, w, E, Bu, vel = self._poses(s, o)
            F = R_cb.shape[0]
            Rc, tc = s["Rci"][0][o.camera], s["tci"][0][o.camera]
            # the camera pose's left perturbation (phi, rho), x_c <- x_c + phi x x_c + rho, by the local unknowns: with
            # R(t) <- R(t) exp(eps), phi = phi_cam - R_cam_imu eps and rho = dt_cam + [t_cam_imu]_x phi - R_cb dp;
            # the time moves with the shift (and with the row delay times the row)
            dphi = R_cb.new_zeros(F, 3, n_loc)
            dphi[:, :, :12] = (-Rc[:, None] @ E).permute(0, 2, 1, 3).reshape(F, 3, 12)
            dphi[:, :, 24:27] = eye
            dphi[:, :, 30] = -(Rc @ w[..., None])[..., 0]
            drho = skew(tc) @ dphi
            drho[:, :, 12:24] -= (R_cb[:, :, None, :] * Bu[:, None, :, None]).reshape(F, 3, 12)
            drho[:, :, 27:30] += eye
            drho[:, :, 30] -= (R_cb @ vel[..., None])[..., 0]
            if self.rolling_shutter:
                dphi[:, :, 31] = dphi[:, :, 30] * o.rows[:, None]
                drho[:, :, 31] = drho[:, :, 30] * o.rows[:, None]
            Jpose = torch.cat([dphi, drho], 1)  # (F, 6, n_loc)
            uv, Jx, xc, Jp = self._project(s, R_cb, t_cb, o, jacobians=True)
            Jcorner = torch.cat([Jx @ -skew(xc), Jx], -1)  # (F, P, 2, 6)
            wgt = o.seen.to(dtype)[..., None] * sp
            r = torch.where(o.seen[..., None], uv - o.corners, 0.0) * wgt
            Jfull = (Jcorner * wgt[..., None]) @ Jpose[:, None]  # (F, P, 2, n_loc)
            if self.NP:
                Jfull[..., 24 + self.P0:24 + K] = Jp * wgt[..., None]
            if self.NW:  # d x_cam / d c_k = R_cam_board e_z b_k(X)
                dz = (Jx * R_cb[:, None, None, :, 2]).sum(-1)  # (F, P, 2)
                Jfull[..., 24 + K:] = (dz * wgt)[..., None] * o.sag[:, :, None, :]
            Hf = torch.einsum("fpia,fpib->fab", Jfull, Jfull)
            bf = torch.einsum("fpia,fpi->fa", Jfull, r)
            pos = [loc.expand(F, 24), 4 * ITEM + K * o.camera[:, None] + torch.arange(K, device=device)]
            if self.NW:
                pos.append((4 * ITEM + self.G_all - 2 + torch.arange(2, device=device)).expand(F, 2))
            pos = torch.cat(pos, 1)
            flat = (pos[:, :, None] * self.L + pos[:, None, :]).flatten(1)
            H.view(H.shape[0], -1).index_put_((seg[:, None].expand_as(flat), flat), Hf.flatten(1), accumulate=True)
            b.index_put_((seg[:, None].expand_as(pos), pos), bf, accumulate=True)
            cost = cost + (r * r).sum()
        return cost

    def _segment_blocks(self, s):
        S = self.M - 3
        dtype, device = s["p"].dtype, s["p"].device
        H = torch.zeros(S, self.L, self.L, dtype=dtype, device=device)
        b = torch.zeros(S, self.L, dtype=dtype, device=device)
        cost = self._imu_blocks(s, H, b) + self._frame_blocks(s, H, b)
        return H, b, cost

    def _spread(self, H, b, cost, s) -> NormalEquations:
        """The banded normal equations from the per-segment blocks and the biases' random walk."""
        M, G, k = self.M, self.G_all, ITEM
        dtype, device = H.dtype, H.device
        S = H.shape[0]
        seg = torch.arange(S, device=device)
        V = torch.zeros(M, k, k, dtype=dtype, device=device)
        Vb = torch.zeros(M, 3, k, k, dtype=dtype, device=device)
        W = torch.zeros(M, G, k, dtype=dtype, device=device)
        ep = torch.zeros(M, k, dtype=dtype, device=device)
        g0 = 4 * k
        for a in range(4):
            V.index_add_(0, seg + a, H[:, a * k:(a + 1) * k, a * k:(a + 1) * k])
            W.index_add_(0, seg + a, H[:, g0:, a * k:(a + 1) * k])
            ep.index_add_(0, seg + a, b[:, a * k:(a + 1) * k])
            for c in range(a + 1, 4):
                Vb[:, c - a - 1].index_add_(0, seg + a, H[:, a * k:(a + 1) * k, c * k:(c + 1) * k])
        U = H[:, g0:, g0:].sum(0)
        eg = b[:, g0:].sum(0)
        # the biases' random walk between neighbouring control points
        walk = torch.cat([s["bg"][0, 1:] - s["bg"][0, :-1], s["ba"][0, 1:] - s["ba"][0, :-1]], -1)  # (M-1, 6)
        wts = torch.tensor([self.w.gyro_walk] * 3 + [self.w.accel_walk] * 3, dtype=dtype, device=device)
        cost = cost + (walk * walk * wts).sum()
        Dw = torch.diag(wts)
        V[:-1, 6:, 6:] += Dw
        V[1:, 6:, 6:] += Dw
        Vb[:-1, 0, 6:, 6:] -= Dw
        ep[:-1, 6:] -= walk * wts
        ep[1:, 6:] += walk * wts
        if self.P is not None:
            U, eg, W = self.P.T @ U @ self.P, self.P.T @ eg, self.P.T @ W
        return NormalEquations(cost=cost.reshape(1), U=U[None], eg=eg[None], W=W[None], V=V[None], ep=ep[None],
                               Vband=Vb[None])
