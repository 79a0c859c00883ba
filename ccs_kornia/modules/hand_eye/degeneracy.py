r"""Hand-eye data that cannot give a trustworthy answer, refused before the fit with the poses it concerns.

Checked on the robot's chain ``A_v`` and the board's pose ``M_v`` seen in each view (``x_camera = M_v p``):

* **too few poses**: fewer than :data:`MIN_POSES` views with both a board and a robot pose;
* **tiny rotations**: the robot's rotations spread less than :data:`TINY_ROTATION_DEG` (RMS about their mean, along
  the principal axis): without rotation the camera's offset on the robot cannot be told from the board's
  (every closed form divides by the motions' rotations; the joint fit's uncertainty grows without bound);
* **rotations about one axis only**: the spread about the second principal axis is below :data:`ONE_AXIS_DEG`: the
  translation along that axis is not determined; below :data:`WEAK_AXIS_DEG` it is a warning;
* **robot and camera disagree**: the rotation between two poses is the same angle seen from the robot and from the
  camera (``A_j A_i^{-1}`` and ``M_j M_i^{-1}`` are conjugate); a pose whose median disagreement with the others
  exceeds :data:`AGREE_DEG` is named (an image paired with another pose, a pose in another rotation format), and all
  of them when most disagree;
* **robot and camera scales disagree**: with ``X``'s rotation known, ``(R_A - I) t_X = s R_X t_B - t_A`` over the
  pairs gives the ratio ``s`` of the robot's translations to the camera's; outside :data:`SCALE_RANGE` the poses'
  unit (m or mm), the board's square size, or the poses' convention is wrong (inverted poses, or the other set-up,
  give a ratio in range once inverted), and the message says which.

Each problem gets a list of issues ``{"severity": "error" | "warning", "check": str, "message": str,
"poses": [view indices]}``; an error refuses the problem.
"""

from __future__ import annotations

import math

import torch

from ccs_kornia.geometry.so3 import log_so3
from ccs_kornia.modules.hand_eye.closed_forms import (
    motion_pairs,
    park_martin,
    project_rotation,
)
from ccs_kornia.modules.hand_eye.setup import invert_transforms

__all__ = ["AGREE_DEG", "MIN_POSES", "ONE_AXIS_DEG", "SCALE_RANGE", "TINY_ROTATION_DEG", "WEAK_AXIS_DEG",
           "hand_eye_issues", "rotation_spread", "translation_scale"]

#: views with a board and a robot pose needed at least (ten or more give a usable uncertainty)
MIN_POSES = 3
#: the robot's rotations must spread at least this much (degrees, RMS about their mean, principal axis)
TINY_ROTATION_DEG = 2.0
#: ... and at least this much about a second axis (degrees)
ONE_AXIS_DEG = 1.0
#: below this spread about the second axis the answer is weak (a warning)
WEAK_AXIS_DEG = 5.0
#: a pose whose rotations to the others differ by more than this (median, degrees) between robot and camera disagrees
AGREE_DEG = 3.0
#: the ratio of the robot's translations to the camera's must lie in this range
SCALE_RANGE = (0.5, 2.0)


def rotation_spread(R: torch.Tensor, valid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """RMS spread (radians) of rotations about their mean along the three principal axes, largest first
    :math:`(B, 3)`, and the axes :math:`(B, 3, 3)` (columns, in the rotations' frame).

    Args:
        R: :math:`(B, V, 3, 3)` rotations; valid: :math:`(B, V)` the ones to count.

    Example:
        >>> from ccs_kornia.geometry.so3 import exp_so3
        >>> w = torch.tensor([[[0.0, 0.0, a] for a in (-0.2, 0.0, 0.2)]], dtype=torch.float64)
        >>> s, axes = rotation_spread(exp_so3(w), torch.ones(1, 3, dtype=torch.bool))
        >>> [round(float(x), 4) for x in s[0]], [round(abs(float(x)), 3) for x in axes[0, :, 0]]
        ([0.1633, 0.0, 0.0], [0.0, 0.0, 1.0])
    """
    m = valid.to(R.dtype)
    mean = project_rotation((R * m[..., None, None]).sum(1))
    rho = log_so3(mean[:, None].transpose(-1, -2) @ R) * m[..., None]
    n = m.sum(1).clamp_min(1)
    centre = rho.sum(1) / n[:, None]
    d = (rho - centre[:, None]) * m[..., None]
    C = d.transpose(-1, -2) @ d / n[:, None, None]
    vals, vecs = torch.linalg.eigh(C)
    return vals.flip(-1).clamp_min(0).sqrt(), vecs.flip(-1)


def translation_scale(A: torch.Tensor, M: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """The ratio ``s`` :math:`(B,)` of the robot's translations to the camera's (module doc), 1 for agreeing data."""
    R_X = park_martin(A, M, valid)[:, :3, :3]
    motion_a, motion_b, ok, _, _ = motion_pairs(A, M, valid)
    eye = torch.eye(3, dtype=A.dtype, device=A.device)
    # (R_A - I) t_X - s R_X t_B = -t_A, unknowns (t_X, s)
    C = torch.cat([motion_a[..., :3, :3] - eye, -(R_X[:, None] @ motion_b[..., :3, 3:4])], -1)  # (B, Q, 3, 4)
    C = torch.where(ok[..., None, None], C.nan_to_num(0.0), 0.0)
    d = torch.where(ok[..., None], -motion_a[..., :3, 3].nan_to_num(0.0), 0.0)
    N = (C.transpose(-1, -2) @ C).sum(1)
    b = (C.transpose(-1, -2) @ d[..., None]).sum(1)
    return (torch.linalg.pinv(N) @ b)[:, 3, 0]


def _angles(T: torch.Tensor) -> torch.Tensor:
    return log_so3(T[..., :3, :3]).norm(dim=-1)


def _pose_list(poses: list[int], names: list[str] | None) -> str:
    labels = [names[p] if names else f"pose {p}" for p in poses]
    more = f", ... ({len(labels)} in all)" if len(labels) > 8 else ""
    return ", ".join(labels[:8]) + more


def hand_eye_issues(A: torch.Tensor, M: torch.Tensor, valid: torch.Tensor,
                    names: list[list[str]] | None = None) -> list[list[dict]]:
    """The checks of the module doc on ``B`` problems.

    Args:
        A: :math:`(B, V, 4, 4)` the robot's chain per view.
        M: :math:`(B, V, 4, 4)` the board's pose in the camera per view.
        valid: :math:`(B, V)` views with a board and a robot pose.
        names: optional per problem, per view labels for the messages (default ``pose v``).

    Returns:
        Per problem, the list of issues (errors refuse the problem).

    Example:
        >>> from ccs_kornia.geometry.so3 import exp_so3
        >>> T = torch.eye(4, dtype=torch.float64).repeat(1, 4, 1, 1)
        >>> T[0, :, :3, :3] = exp_so3(torch.tensor([[0.0, 0, 0], [0.3, 0, 0], [0.6, 0, 0], [0.9, 0, 0]]).double())
        >>> [i["check"] for i in hand_eye_issues(T, T, torch.ones(1, 4, dtype=torch.bool))[0]]
        ['one_axis']
    """
    B, V = valid.shape
    deg = 180.0 / math.pi
    out: list[list[dict]] = []
    spread, axes = rotation_spread(A[..., :3, :3], valid)
    motion_a, motion_b, ok, pi, pj = motion_pairs(A, M, valid)
    mismatch = (_angles(motion_a) - _angles(motion_b)).abs() * deg  # (B, Q)
    scale = inverted = None
    for b in range(B):
        issues: list[dict] = []
        labels = names[b] if names else None
        used = torch.nonzero(valid[b]).flatten().tolist()
        out.append(issues)
        if len(used) < MIN_POSES:
            issues.append({"severity": "error", "check": "too_few_poses", "poses": used,
                           "message": f"{len(used)} pose(s) with the board seen; at least {MIN_POSES} are needed "
                                      "(ten or more, rotated about different axes, give a trustworthy answer)"})
            continue
        s1, s2 = float(spread[b, 0]) * deg, float(spread[b, 1]) * deg
        if s1 < TINY_ROTATION_DEG:
            issues.append({"severity": "error", "check": "tiny_rotation", "poses": used,
                           "message": f"the robot barely rotates between the poses ({_pose_list(used, labels)}): "
                                      f"{s1:.2f} deg RMS about their mean, at least {TINY_ROTATION_DEG:g} is needed; "
                                      "without rotation the camera's place on the robot cannot be told from the "
                                      "board's: tilt the flange by 15-30 degrees about different axes between poses"})
            continue
        if s2 < ONE_AXIS_DEG or s2 < WEAK_AXIS_DEG:
            axis = axes[b, :, 0].tolist()
            text = (f"the robot rotates about one axis only (about ({axis[0]:.2f}, {axis[1]:.2f}, {axis[2]:.2f}); "
                    f"{s2:.2f} deg RMS about any other)")
            if s2 < ONE_AXIS_DEG:
                issues.append({"severity": "error", "check": "one_axis", "poses": used,
                               "message": f"{text} over the poses {_pose_list(used, labels)}: the translation along "
                                          "that axis is not determined; add poses rotated about other axes"})
                continue
            issues.append({"severity": "warning", "check": "weak_axis", "poses": used,
                           "message": f"{text}: the answer is weak along that axis; add poses rotated about other "
                                      "axes"})
        good = ok[b]
        if bool(good.any()):
            per_pose = []
            for v in used:
                mine = good & ((pi == v) | (pj == v))
                per_pose.append(float(mismatch[b][mine].median()) if bool(mine.any()) else 0.0)
            bad = [v for v, m in zip(used, per_pose) if m > AGREE_DEG]
            overall = float(mismatch[b][good].median())
            if overall > AGREE_DEG or len(bad) > len(used) // 2:
                issues.append({"severity": "error", "check": "disagree", "poses": used,
                               "message": f"the robot's poses and the images do not agree: the rotations between "
                                          f"poses differ by {overall:.1f} deg (median) between the robot and the "
                                          "camera; check that each pose belongs to its image (file names in the "
                                          "pose file), the rotation format (--pose-format: quaternion order x,y,z,w; "
                                          "rotation vectors in radians) and the pose convention (the flange in the "
                                          "base frame)"})
                continue
            if bad:
                worst = max(per_pose)
                issues.append({"severity": "error", "check": "disagree", "poses": bad,
                               "message": f"{_pose_list(bad, labels)}: the robot's pose and the image disagree (the "
                                          f"rotations to the other poses differ by up to {worst:.1f} deg between the "
                                          "robot and the camera): a pose paired with another image, or a robot "
                                          "that moved after its pose was read; remove or re-record them"})
                continue
        if scale is None:
            scale = translation_scale(A, M, valid)
        s = float(scale[b])
        if math.isfinite(s) and not (SCALE_RANGE[0] <= s <= SCALE_RANGE[1]):
            if inverted is None:
                inverted = translation_scale(invert_transforms(A), M, valid)
            s_inv = float(inverted[b])
            if SCALE_RANGE[0] <= s_inv <= SCALE_RANGE[1]:
                hint = (f"with the poses inverted they agree ({s_inv:.3g}): the poses look like the base in the flange "
                        "frame (give the flange in the base frame, x_base = T x_flange), or the set-up is the other "
                        "one (--eye-in-hand / --eye-to-hand)")
            elif s > 100:
                hint = "the robot's translations look like millimetres read as metres: --pose-units mm"
            elif s < 0.01:
                hint = ("the robot's translations look like metres read as millimetres (--pose-units m), or the "
                        "board's size is in millimetres (--square and --tag-size are in metres)")
            else:
                hint = "check --square (the board's unit must be the robot's: metres) and --pose-units"
            issues.append({"severity": "error", "check": "scale", "poses": used,
                           "message": f"the robot's translations are {s:.4g} times the camera's: {hint}"})
    return out
