"""Corner-level renderer of camera rigs: exact board corners seen by C cameras over F frames (no images).

Each frame places one board in front of the rig (a pose board -> camera 0); each camera projects it through its own
model (:class:`~ccs_kornia.geometry.camera.Camera`). A corner is invalid (NaN, ``valid = False``) where it falls
outside the camera's image, behind it or beyond ``max_angle_deg`` from its axis, or where the camera drops the frame
(``drop``). Optional Gaussian pixel noise is added to
the valid corners. The ground truth is exact; nothing here imports the solver.

Example:
    >>> import torch
    >>> from ccs_kornia.geometry.models import PINHOLE
    >>> cams = Camera(PINHOLE, torch.tensor([[500., 500, 320, 240]] * 2, dtype=torch.float64), (640, 480))
    >>> scene = render_rig(cams, R=torch.eye(3, dtype=torch.float64).expand(2, 3, 3),
    ...                    T=torch.tensor([[0.0, 0, 0], [-0.1, 0, 0]], dtype=torch.float64), num_frames=4, seed=0)
    >>> scene.corners.shape, scene.valid.shape, scene.object_points.shape
    (torch.Size([2, 4, 35, 2]), torch.Size([2, 4, 35]), torch.Size([35, 3]))
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.board_warp import warped_board
from ccs_kornia.geometry.camera import (
    Camera,
    axis_angle_to_rotation_matrix,
    rotation_matrix_to_axis_angle,
)

__all__ = ["RigScene", "random_board_poses", "render_rig"]


@dataclass
class RigScene:
    """A rendered rig: observations and their exact ground truth (C cameras, F frames, N corners)."""

    corners: torch.Tensor  #: (C, F, N, 2) px, NaN where not seen
    valid: torch.Tensor  #: (C, F, N) bool
    object_points: torch.Tensor  #: (N, 3) board points
    image_sizes: list[tuple[int, int]]  #: (W, H) per camera
    cameras: Camera  #: the C cameras (float64)
    R: torch.Tensor  #: (C, 3, 3) x_c = R_c x_0 + T_c
    T: torch.Tensor  #: (C, 3)
    board_rvec: torch.Tensor  #: (F, 3) board -> camera 0
    board_tvec: torch.Tensor  #: (F, 3)
    exact: torch.Tensor  #: (C, F, N, 2) noise-free projections of the valid corners (NaN elsewhere)


def random_board_poses(
    num_frames: int,
    object_points: torch.Tensor,
    generator: torch.Generator,
    distance: tuple[float, float] = (0.6, 1.4),
    spread: float = 0.35,
    tilt_deg: float = 40.0,
    look: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Random board poses (board -> camera 0) facing the rig: centre at ``distance`` along a direction within
    ``spread`` rad of ``look`` (default the optical axis of camera 0), tilted up to ``tilt_deg`` about a random axis
    in the board plane and turned about its normal by up to 30 degrees.

    Returns:
        ``rvec`` :math:`(F, 3)` and ``tvec`` :math:`(F, 3)`.
    """
    dtype = object_points.dtype
    g = generator
    look = torch.tensor([0.0, 0.0, 1.0], dtype=dtype) if look is None else look.to(dtype) / look.to(dtype).norm()
    centre = object_points.mean(0)

    def rand(*shape):
        return torch.rand(*shape, generator=g, dtype=dtype)

    dist = distance[0] + (distance[1] - distance[0]) * rand(num_frames)
    ang = spread * rand(num_frames).sqrt()
    phi = 2 * math.pi * rand(num_frames)
    # a direction within `ang` of `look`: rotate look by ang about an axis perpendicular to it
    perp = torch.linalg.cross(look, torch.tensor([1.0, 0.0, 0.0], dtype=dtype))
    if perp.norm() < 1e-6:
        perp = torch.linalg.cross(look, torch.tensor([0.0, 1.0, 0.0], dtype=dtype))
    perp = perp / perp.norm()
    perp2 = torch.linalg.cross(look, perp)
    axis = phi.cos()[:, None] * perp + phi.sin()[:, None] * perp2
    dirs = axis_angle_to_rotation_matrix(axis * ang[:, None]) @ look
    target = dirs * dist[:, None]
    # board facing the rig: board z along the viewing direction, then a tilt and a turn about the normal
    tilt_axis_phi = 2 * math.pi * rand(num_frames)
    tilt = math.radians(tilt_deg) * rand(num_frames)
    tilt_v = torch.stack([tilt_axis_phi.cos(), tilt_axis_phi.sin(), torch.zeros_like(tilt)], -1) * tilt[:, None]
    turn = torch.stack([torch.zeros_like(tilt), torch.zeros_like(tilt), math.radians(30) * (2 * rand(num_frames) - 1)], -1)
    z = torch.tensor([0.0, 0.0, 1.0], dtype=dtype)
    zx = torch.linalg.cross(z, look)  # rotation taking the camera axis to `look`
    s = zx.norm()
    w = zx * (torch.atan2(s, look[2]) / s) if float(s) > 1e-12 else torch.zeros(3, dtype=dtype)
    R_face = axis_angle_to_rotation_matrix(w[None]).expand(num_frames, 3, 3)
    R = R_face @ axis_angle_to_rotation_matrix(tilt_v) @ axis_angle_to_rotation_matrix(turn)
    tvec = target - (R @ centre)
    return rotation_matrix_to_axis_angle(R), tvec


def render_rig(
    cameras: Camera,
    R: torch.Tensor,
    T: torch.Tensor,
    num_frames: int = 12,
    seed: int = 0,
    board: tuple[int, int] = (7, 5),
    square: float = 0.05,
    noise_px: float = 0.0,
    drop: float = 0.0,
    board_poses: tuple[torch.Tensor, torch.Tensor] | None = None,
    max_angle_deg: float = 85.0,
    board_warp: tuple[float, float] | None = None,
    **pose_kw,
) -> RigScene:
    """Render the corners a rig sees.

    Args:
        cameras: the C cameras, each with its image size.
        R: :math:`(C, 3, 3)` extrinsic rotations, ``x_c = R_c x_0 + T_c``.
        T: :math:`(C, 3)` extrinsic translations (board units).
        num_frames: frames F.
        seed: seed of the board poses, noise and drops.
        board: ``(cols, rows)`` inner corners.
        square: square side.
        noise_px: standard deviation of the Gaussian pixel noise.
        drop: probability that a camera misses a frame (all its corners invalid).
        board_poses: explicit ``(rvec (F, 3), tvec (F, 3))`` board -> camera 0 (else :func:`random_board_poses`).
        max_angle_deg: a corner further than this from a camera's axis is not seen.
        board_warp: the board's sag ``(c_x, c_y)`` (mrcal's ``calobject_warp``, board units,
            :mod:`~ccs_kornia.geometry.board_warp`): the corners are those of the bent board (``object_points`` stay
            the flat board's, as a solver is given them); ``None``: a flat board.
        pose_kw: options of :func:`random_board_poses`.

    Returns:
        :class:`RigScene`.
    """
    C = len(cameras)
    image_sizes = cameras.image_sizes
    if any(s is None for s in image_sizes) or R.shape != (C, 3, 3) or T.shape != (C, 3):
        raise ValueError(f"cameras (with their image sizes), R (C, 3, 3) and T (C, 3) must agree on C={C}.")
    dtype = torch.float64
    cameras = cameras.to(dtype=dtype)
    g = torch.Generator().manual_seed(int(seed))
    obj = board_object_points(board[0], board[1], square, dtype=dtype)
    N = obj.shape[0]
    if board_poses is None:
        rvec, tvec = random_board_poses(num_frames, obj, g, **pose_kw)
    else:
        rvec, tvec = (p.to(dtype) for p in board_poses)
    F = rvec.shape[0]
    Rb = axis_angle_to_rotation_matrix(rvec)
    shape = obj if board_warp is None else warped_board(obj, torch.tensor(board_warp, dtype=dtype))
    x0 = shape @ Rb.transpose(-1, -2) + tvec[:, None]  # (F, N, 3) in camera 0
    corners = torch.full((C, F, N, 2), float("nan"), dtype=dtype)
    valid = torch.zeros(C, F, N, dtype=torch.bool)
    for c in range(C):
        Rc, Tc = R[c].to(dtype), T[c].to(dtype)
        xc = x0 @ Rc.T + Tc
        cam = cameras[c]
        uv = cam.project(xc[None])[0]
        W, H = image_sizes[c]
        angle = torch.atan2(xc[..., :2].norm(dim=-1), xc[..., 2])
        inside = (uv[..., 0] >= 0) & (uv[..., 0] <= W - 1) & (uv[..., 1] >= 0) & (uv[..., 1] <= H - 1)
        seen = inside & (angle < math.radians(max_angle_deg)) & uv.isfinite().all(-1) & cam.visible(xc[None])[0]
        if drop > 0:
            seen = seen & (torch.rand(F, generator=g, dtype=dtype) >= drop)[:, None]
        valid[c] = seen
        corners[c] = torch.where(seen[..., None], uv, float("nan"))
    exact = corners.clone()
    if noise_px > 0:
        corners = corners + noise_px * torch.randn(corners.shape, generator=g, dtype=dtype)
    return RigScene(
        corners=corners, valid=valid, object_points=obj, image_sizes=[tuple(map(int, s)) for s in image_sizes],
        cameras=cameras, R=R.to(dtype).clone(), T=T.to(dtype).clone(), board_rvec=rvec, board_tvec=tvec, exact=exact,
    )
