r"""Rendered robots for hand-eye calibration: a 7-joint arm, a camera and a board, with exact ground truth.

The arm is Franka's Panda (its published modified Denavit-Hartenberg parameters and joint limits,
:func:`panda_flange_poses`). A scene (:func:`render_hand_eye`) fixes the camera's pose ``X`` and the board's ``Z``
(:mod:`~ccs_kornia.modules.hand_eye.setup`'s conventions), draws views around a nominal one (the camera looking at
the board from 0.35-0.6 m for eye-in-hand, the board held up to a camera 0.5-0.9 m away for eye-to-hand), reaches each
by inverse kinematics (damped least squares from the arm's ready pose), then:

* the corners are the board's points projected through the true flange pose and the camera (OpenCV's ``k1, k2``
  lens, :attr:`HandEyeScene.camera`), plus Gaussian pixel noise;
* the *reported* flange pose is the forward kinematics of the joint angles plus Gaussian joint noise (encoder
  error): the robot-pose noise a real arm adds, in joint space;
* optionally, the errors of a real arm's kinematics: the *true* arm's joint offsets and link lengths differ from the
  published parameters the controller reports with (``joint_offset_deg``, ``link_error_mm``: one draw per scene, so
  the error of each pose depends on the pose), and a time offset between the image and the reported pose while the
  arm moves on through the view towards the next one (``time_offset_s``, ``move_s``).

``max_tilt_deg`` bounds the views' tilt about the nominal view (30 degrees: the rotation hand-eye needs; 4: the small
rotations that break the closed forms). The renderer depends on :mod:`ccs_kornia.geometry` only.

Example:
    >>> scene = render_hand_eye("eye_in_hand", views=6, seed=0)
    >>> scene.corners.shape, scene.robot_poses.shape, bool(scene.valid.all())
    (torch.Size([6, 54, 2]), torch.Size([6, 4, 4]), True)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models.factory import K1K2
from ccs_kornia.geometry.so3 import exp_so3, log_so3

__all__ = ["PANDA_DH", "PANDA_LIMITS", "PANDA_READY", "HandEyeScene", "panda_flange_poses", "panda_ik",
           "render_hand_eye"]

#: Panda's modified DH parameters (a_{i-1}, d_i, alpha_{i-1}) of joints 1-7 and the flange
PANDA_DH = ((0.0, 0.333, 0.0), (0.0, 0.0, -math.pi / 2), (0.0, 0.316, math.pi / 2), (0.0825, 0.0, math.pi / 2),
            (-0.0825, 0.384, -math.pi / 2), (0.0, 0.0, math.pi / 2), (0.088, 0.0, math.pi / 2), (0.0, 0.107, 0.0))
#: joint limits (rad)
PANDA_LIMITS = ((-2.8973, 2.8973), (-1.7628, 1.7628), (-2.8973, 2.8973), (-3.0718, -0.0698), (-2.8973, 2.8973),
                (-0.0175, 3.7525), (-2.8973, 2.8973))
#: the arm's ready pose (rad)
PANDA_READY = (0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4)


def _rot(axis: str, a: torch.Tensor) -> torch.Tensor:
    c, s = a.cos(), a.sin()
    o, z = torch.ones_like(a), torch.zeros_like(a)
    rows = {"x": [o, z, z, z, c, -s, z, s, c], "z": [c, -s, z, s, c, z, z, z, o]}[axis]
    return torch.stack(rows, -1).reshape(*a.shape, 3, 3)


def _pose(R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    T = torch.zeros(*R.shape[:-2], 4, 4, dtype=R.dtype, device=R.device)
    T[..., :3, :3], T[..., :3, 3], T[..., 3, 3] = R, t, 1.0
    return T


def panda_flange_poses(q: torch.Tensor, joint_offsets: torch.Tensor | None = None,
                       link_errors: torch.Tensor | None = None) -> torch.Tensor:
    """The flange's pose in the base frame :math:`(*, 4, 4)` (``x_base = T x_flange``) of joint angles
    :math:`(*, 7)` (forward kinematics, modified DH: ``RotX(alpha) TransX(a) RotZ(theta) TransZ(d)``); an arm whose
    kinematics differ from the published ones: ``joint_offsets`` :math:`(7,)` added to the joint angles (radians),
    ``link_errors`` :math:`(8, 2)` added to each row's ``a`` and ``d`` (metres).

    Example:
        >>> T = panda_flange_poses(torch.tensor(PANDA_READY, dtype=torch.float64))
        >>> [round(float(x), 3) + 0.0 for x in T[:3, 3]]
        [0.307, 0.0, 0.59]
    """
    T = torch.eye(4, dtype=q.dtype, device=q.device).expand(*q.shape[:-1], 4, 4)
    zero = torch.zeros_like(q[..., 0])
    if joint_offsets is not None:
        q = q + joint_offsets.to(q)
    for i, (a, d, alpha) in enumerate(PANDA_DH):
        theta = q[..., i] if i < 7 else zero
        if link_errors is not None:
            a, d = a + float(link_errors[i, 0]), d + float(link_errors[i, 1])
        R = _rot("x", torch.full_like(zero, alpha)) @ _rot("z", theta)
        t = torch.stack([torch.full_like(zero, a), -math.sin(alpha) * torch.full_like(zero, d),
                         math.cos(alpha) * torch.full_like(zero, d)], -1)
        T = T @ _pose(R, t)
    return T


def _error(T: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    return torch.cat([target[..., :3, 3] - T[..., :3, 3], log_so3(target[..., :3, :3] @ T[..., :3, :3].transpose(-1, -2))],
                     -1)


def panda_ik(target: torch.Tensor, iters: int = 200, start: torch.Tensor | None = None
             ) -> tuple[torch.Tensor, torch.Tensor]:
    """Joint angles :math:`(*, 7)` reaching flange poses :math:`(*, 4, 4)` (damped least squares from the ready pose,
    joint limits enforced) and whether each was reached (1e-9 m and rad)."""
    lo = torch.tensor([a for a, _ in PANDA_LIMITS], dtype=target.dtype, device=target.device)
    hi = torch.tensor([b for _, b in PANDA_LIMITS], dtype=target.dtype, device=target.device)
    q = torch.tensor(PANDA_READY, dtype=target.dtype, device=target.device).expand(*target.shape[:-2], 7).clone() \
        if start is None else start.clone()
    eps = 1e-7
    for _ in range(iters):
        e = _error(panda_flange_poses(q), target)
        cols = []
        for k in range(7):
            dq = torch.zeros_like(q)
            dq[..., k] = eps
            cols.append((e - _error(panda_flange_poses(q + dq), target)) / eps)
        J = torch.stack(cols, -1)  # d(-e)/dq
        JJt = J @ J.transpose(-1, -2) + 1e-4 * torch.eye(6, dtype=q.dtype, device=q.device)
        q = torch.minimum(torch.maximum(q + (J.transpose(-1, -2) @ torch.linalg.solve(JJt, e[..., None]))[..., 0], lo),
                          hi)
    e = _error(panda_flange_poses(q), target)
    return q, e.abs().amax(-1) < 1e-9


@dataclass
class HandEyeScene:
    """A rendered hand-eye data set (``V`` views, ``N`` board corners; translations in metres)."""

    setup: str  #: "eye_in_hand" or "eye_to_hand"
    X: torch.Tensor  #: (4, 4) the camera's pose in its robot frame (the truth)
    Z: torch.Tensor  #: (4, 4) the board's pose in its robot frame (the truth)
    K: torch.Tensor  #: (3, 3)
    dist: torch.Tensor  #: (2,) k1, k2
    image_size: tuple[int, int]
    object_points: torch.Tensor  #: (N, 3)
    joints: torch.Tensor  #: (V, 7) true joint angles
    true_poses: torch.Tensor  #: (V, 4, 4) true flange poses
    robot_poses: torch.Tensor  #: (V, 4, 4) reported flange poses (joint noise)
    corners: torch.Tensor  #: (V, N, 2) observed corners (pixel noise)
    valid: torch.Tensor  #: (V, N) bool
    noise_px: float
    joint_noise_deg: float
    joint_offsets: torch.Tensor | None = None  #: (7,) the true arm's joint offsets (radians), where drawn
    link_errors: torch.Tensor | None = None  #: (8, 2) the true arm's errors of each DH row's a and d (m), where drawn
    time_offset_s: float = 0.0  #: the reported pose's lag behind the image (s)

    @property
    def camera(self) -> Camera:
        """The true camera (OpenCV's ``k1, k2`` model) with its image size."""
        return Camera.from_opencv(K1K2, self.K, self.dist, self.image_size)


def _look(direction: torch.Tensor, roll: float) -> torch.Tensor:
    """A rotation whose z axis is ``direction`` (columns x, y, z), turned by ``roll`` about it."""
    z = direction / direction.norm()
    up = torch.tensor([0.0, 0.0, 1.0], dtype=z.dtype) if abs(float(z[2])) < 0.9 else torch.tensor([1.0, 0, 0]).to(z)
    x = torch.linalg.cross(up, z)
    x = x / x.norm()
    y = torch.linalg.cross(z, x)
    return torch.stack([x, y, z], -1) @ exp_so3(torch.tensor([0.0, 0.0, roll], dtype=z.dtype))


def render_hand_eye(
    setup: str,
    views: int = 15,
    seed: int = 0,
    noise_px: float = 0.2,
    joint_noise_deg: float = 0.01,
    max_tilt_deg: float = 30.0,
    board: tuple[int, int] = (9, 6),
    square: float = 0.025,
    image_size: tuple[int, int] = (640, 480),
    max_tries: int = 40,
    joint_offset_deg: float = 0.0,
    link_error_mm: float = 0.0,
    time_offset_s: float = 0.0,
    move_s: float = 2.0,
) -> HandEyeScene:
    """A random hand-eye scene (module doc) with ``views`` views in which the whole board is seen.

    Args:
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        views: number of views.
        seed: the scene's seed (camera, mounting, views, noise).
        noise_px: pixel noise (sigma, px).
        joint_noise_deg: joint-angle noise of the reported poses (sigma, degrees).
        max_tilt_deg: the views' tilt about the nominal view, at most (degrees; roll is drawn within the same bound).
        board, square: the chessboard's inner corners and square side (m).
        image_size: ``(W, H)``.
        max_tries: rounds of candidate views drawn before giving up.
        joint_offset_deg: the true arm's joint offsets against the reported kinematics (sigma, degrees; one draw per
            scene).
        link_error_mm: the true arm's link-length errors (sigma of each DH ``a`` and ``d``, millimetres; one draw).
        time_offset_s: the reported pose lags the image by this while the arm moves at a constant joint velocity
            from each view towards the next (``move_s`` seconds between views; the last view keeps the motion it
            came with).
    """
    if setup not in ("eye_in_hand", "eye_to_hand"):
        raise ValueError(f"unknown set-up {setup!r}; expected eye_in_hand or eye_to_hand")
    g = torch.Generator().manual_seed(int(seed))
    dt = torch.float64

    def uni(lo: float, hi: float, *shape: int) -> torch.Tensor:
        return lo + (hi - lo) * torch.rand(*shape, generator=g, dtype=dt)

    W, H = image_size
    f = float(uni(550, 700, 1))
    K = torch.tensor([[f, 0, (W - 1) / 2 + float(uni(-8, 8, 1))], [0, f * float(uni(0.995, 1.005, 1)),
                      (H - 1) / 2 + float(uni(-8, 8, 1))], [0, 0, 1]], dtype=dt)
    dist = torch.tensor([float(uni(-0.15, 0.0, 1)), float(uni(0.0, 0.05, 1))], dtype=dt)
    lens = Camera.from_opencv(K1K2, K, dist)
    obj = board_object_points(board[0], board[1], square, dtype=dt)
    centre = obj.mean(0)
    tilt = math.radians(max_tilt_deg)
    if setup == "eye_in_hand":
        # the board on the table, face up (its z axis, into the print, points down); the camera on the flange
        RZ = _rot("z", uni(-0.5, 0.5, 1)[0]) @ torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=dt))
        tZ = torch.tensor([0.45, 0.0, 0.0], dtype=dt) + uni(-0.05, 0.05, 3) * torch.tensor([1, 1, 0], dtype=dt)
        tZ = tZ - RZ @ centre
        Z = _pose(RZ, tZ)
        X = _pose(exp_so3(uni(-0.15, 0.15, 3)), torch.tensor([0.05, 0.0, 0.04], dtype=dt) + uni(-0.03, 0.03, 3))
    else:
        # the camera in the room looking back at the arm, the board on the flange facing out
        X = _pose(_look(torch.tensor([-1.0, float(uni(-0.2, 0.2, 1)), float(uni(-0.5, -0.2, 1))], dtype=dt),
                        float(uni(-0.2, 0.2, 1))), torch.tensor([1.05, 0.0, 0.55], dtype=dt) + uni(-0.05, 0.05, 3))
        RZ = exp_so3(torch.tensor([math.pi, 0.0, 0.0], dtype=dt)) @ exp_so3(uni(-0.1, 0.1, 3))
        Z = _pose(RZ, torch.tensor([0.0, 0.0, 0.02], dtype=dt) - RZ @ centre + uni(-0.01, 0.01, 3))
    target_in_base = Z[:3, 3] + Z[:3, :3] @ centre if setup == "eye_in_hand" else None
    joints, poses = [], []
    for _ in range(max_tries):
        n = 4 * views
        dirs, rolls = [], []
        for _k in range(n):
            a, b = float(uni(-tilt, tilt, 1)), float(uni(0, 2 * math.pi, 1))
            dirs.append(torch.tensor([math.sin(a) * math.cos(b), math.sin(a) * math.sin(b), math.cos(a)], dtype=dt))
            rolls.append(float(uni(-tilt, tilt, 1)))
        if setup == "eye_in_hand":
            # camera poses in the base frame: looking down at the board's centre from 0.35-0.6 m
            nominal = torch.tensor([0.0, 0.0, -1.0], dtype=dt)
            Rn = _look(nominal, float(uni(-0.3, 0.3, 1)))
            C = []
            for d, r in zip(dirs, rolls):
                Rc = Rn @ _look(d, r)
                dist_m = float(uni(0.35, 0.6, 1))
                aim = target_in_base + uni(-0.04, 0.04, 3) * torch.tensor([1, 1, 0], dtype=dt)
                C.append(_pose(Rc, aim - Rc[:, 2] * dist_m))
            C = torch.stack(C)
            target = C @ torch.linalg.inv(X)
        else:
            # board poses in the camera: facing it from 0.5-0.9 m, near the optical axis
            M = []
            for d, r in zip(dirs, rolls):
                Rb = _look(d, r)
                depth = float(uni(0.5, 0.9, 1))
                pos = torch.tensor([float(uni(-0.12, 0.12, 1)) * depth, float(uni(-0.08, 0.08, 1)) * depth, depth],
                                   dtype=dt)
                M.append(_pose(Rb, pos - Rb @ centre))
            M = torch.stack(M)
            target = X @ M @ torch.linalg.inv(Z)
        q, ok = panda_ik(target)
        T = panda_flange_poses(q)
        if setup == "eye_in_hand":
            cam = torch.linalg.inv(T @ X) @ Z
        else:
            cam = torch.linalg.inv(X) @ T @ Z
        uv = lens.project(obj.expand(1, n, -1, -1), log_so3(cam[:, :3, :3])[None], cam[None, :, :3, 3])[0]
        depth_ok = ((obj @ cam[:, :3, :3].transpose(-1, -2) + cam[:, None, :3, 3])[..., 2] > 0.1).all(-1)
        inside = ((uv[..., 0] > 10) & (uv[..., 0] < W - 11) & (uv[..., 1] > 10) & (uv[..., 1] < H - 11)).all(-1)
        keep = ok & inside & depth_ok
        for k in torch.nonzero(keep).flatten().tolist():
            if len(joints) < views:
                joints.append(q[k])
                poses.append(T[k])
        if len(joints) >= views:
            break
    if len(joints) < views:
        raise RuntimeError(f"only {len(joints)} of {views} views reachable; loosen the scene")
    q = torch.stack(joints)
    q_reported = q + math.radians(joint_noise_deg) * torch.randn(q.shape, generator=g, dtype=dt)
    pixel_noise = noise_px * torch.randn(views, obj.shape[0], 2, generator=g, dtype=dt)
    # the arm's kinematic errors are drawn after the noise: a scene without them is the one drawn before they existed
    offsets = links = None
    if joint_offset_deg > 0 or link_error_mm > 0:
        offsets = math.radians(joint_offset_deg) * torch.randn(7, generator=g, dtype=dt)
        links = link_error_mm / 1000.0 * torch.randn(len(PANDA_DH), 2, generator=g, dtype=dt)
    T = panda_flange_poses(q, offsets, links) if offsets is not None else torch.stack(poses)
    if time_offset_s:
        velocity = torch.cat([q[1:] - q[:-1], q[-1:] - q[-2:-1]]) / move_s if views > 1 else torch.zeros_like(q)
        q_reported = q_reported - velocity * time_offset_s
    reported = panda_flange_poses(q_reported)
    cam = (torch.linalg.inv(T @ X) @ Z) if setup == "eye_in_hand" else (torch.linalg.inv(X) @ T @ Z)
    uv = lens.project(obj.expand(1, views, -1, -1), log_so3(cam[:, :3, :3])[None], cam[None, :, :3, 3])[0]
    uv = uv + pixel_noise
    return HandEyeScene(setup, X, Z, K, dist, image_size, obj, q, T, reported, uv,
                        torch.ones(uv.shape[:2], dtype=torch.bool), float(noise_px), float(joint_noise_deg),
                        offsets, links, float(time_offset_s))
