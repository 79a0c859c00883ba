r"""Closed-form hand-eye estimates from the robot's chain and the board's pose in each view, batched over problems.

With ``M_v`` the board's pose in the camera in view ``v`` (``x_camera = M_v p``, from the view's corners alone) and
``A_v`` the robot's chain (:meth:`~ccs_kornia.modules.hand_eye.setup.HandEyeSetup.chain`), every view gives
``X M_v = A_v Z``. Three classic ways to solve it, each blind to the images once the ``M_v`` are computed:

* :func:`park_martin`: motions between every pair of views, ``A_j A_i^{-1} X = X M_j M_i^{-1}`` (``AX = XB``); the
  rotation aligns the motions' rotation vectors (Park and Martin 1994, Kabsch's SVD), the translation by linear
  least squares;
* :func:`andreff`: the same motions, the rotation as the null vector of the Kronecker form ``R_A R_X = R_X R_B``
  (Andreff et al. 2001), projected on SO(3);
* :func:`robot_world`: the absolute poses, ``X`` and ``Z`` together as the null vector of ``R_X R_M = R_A R_Z``
  (Shah 2013; Li et al. 2010), then both translations by least squares: no motion pairs, so small motions
  weaken it less.

Each returns ``X`` :math:`(B, 4, 4)`; :func:`board_in_robot` gives the board's pose ``Z`` for an ``X`` (the
chordal mean of ``A_v^{-1} X M_v``). The solver starts from whichever fits the corners best
(:mod:`~ccs_kornia.modules.hand_eye.solver`): none of them is always the best (on the same data they can disagree by
centimetres).
"""

from __future__ import annotations

import torch

from ccs_kornia.geometry.so3 import log_so3
from ccs_kornia.modules.hand_eye.setup import invert_transforms

__all__ = ["CLOSED_FORMS", "andreff", "board_in_robot", "closed_form_candidates", "motion_pairs", "park_martin",
           "project_rotation", "robot_world"]


def project_rotation(M: torch.Tensor) -> torch.Tensor:
    """The nearest rotation :math:`(*, 3, 3)` (Frobenius) to each :math:`(*, 3, 3)` matrix (SVD, determinant +1).

    Example:
        >>> project_rotation(2 * torch.eye(3, dtype=torch.float64)).equal(torch.eye(3, dtype=torch.float64))
        True
    """
    U, _, Vh = torch.linalg.svd(M)
    d = torch.linalg.det(U @ Vh)
    D = torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), d], -1))
    return U @ D @ Vh


def _pose(R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    T = torch.zeros(*R.shape[:-2], 4, 4, dtype=R.dtype, device=R.device)
    T[..., :3, :3], T[..., :3, 3], T[..., 3, 3] = R, t, 1.0
    return T


def motion_pairs(A: torch.Tensor, M: torch.Tensor, valid: torch.Tensor
                 ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The motions between every pair ``i < j`` of views: the robot's ``A_j A_i^{-1}`` and the camera's
    ``M_j M_i^{-1}`` :math:`(B, Q, 4, 4)`, ``Q = V (V - 1) / 2``, their mask :math:`(B, Q)` (both views valid) and the
    pair indices ``i, j`` :math:`(Q,)`.

    Example:
        >>> T = torch.eye(4, dtype=torch.float64).expand(1, 3, 4, 4)
        >>> a, b, ok, i, j = motion_pairs(T, T, torch.ones(1, 3, dtype=torch.bool))
        >>> a.shape, i.tolist(), j.tolist()
        (torch.Size([1, 3, 4, 4]), [0, 0, 1], [1, 2, 2])
    """
    V = A.shape[-3]
    i, j = torch.triu_indices(V, V, 1, device=A.device)
    motion_a = A[:, j] @ invert_transforms(A[:, i])
    motion_b = M[:, j] @ invert_transforms(M[:, i])
    return motion_a, motion_b, valid[:, i] & valid[:, j], i, j


def _masked(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    return torch.where(mask.view(*mask.shape, *([1] * (x.dim() - mask.dim()))), x.nan_to_num(0.0), 0.0)


def _translation_from_pairs(motion_a, motion_b, ok, R_X) -> torch.Tensor:
    """``t_X`` of ``(R_A - I) t_X = R_X t_B - t_A`` over the pairs, linear least squares :math:`(B, 3)`."""
    eye = torch.eye(3, dtype=R_X.dtype, device=R_X.device)
    C = _masked(motion_a[..., :3, :3] - eye, ok)  # (B, Q, 3, 3)
    d = _masked((R_X[:, None] @ motion_b[..., :3, 3:4])[..., 0] - motion_a[..., :3, 3], ok)
    N = (C.transpose(-1, -2) @ C).sum(1)
    b = (C.transpose(-1, -2) @ d[..., None]).sum(1)
    return (torch.linalg.pinv(N) @ b)[..., 0]


def park_martin(A: torch.Tensor, M: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """``X`` :math:`(B, 4, 4)` by Park and Martin's method on every pair of valid views (module doc).

    Args:
        A: :math:`(B, V, 4, 4)` the robot's chain per view.
        M: :math:`(B, V, 4, 4)` the board's pose in the camera per view.
        valid: :math:`(B, V)` views to use.

    Example:
        >>> from ccs_kornia.geometry.so3 import exp_so3
        >>> X = _pose(exp_so3(torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)), torch.tensor([0.1, 0.0, 0.05]).double())
        >>> Z = _pose(exp_so3(torch.tensor([0.0, 3.0, 0.1], dtype=torch.float64)), torch.tensor([0.5, 0.2, 0.0]).double())
        >>> A = _pose(exp_so3(torch.randn(1, 5, 3, generator=torch.Generator().manual_seed(0)).double()),
        ...           torch.randn(1, 5, 3, generator=torch.Generator().manual_seed(1)).double())
        >>> M = invert_transforms(X) @ A @ Z
        >>> torch.allclose(park_martin(A, M, torch.ones(1, 5, dtype=torch.bool))[0], X)
        True
    """
    motion_a, motion_b, ok, _, _ = motion_pairs(A, M, valid)
    alpha = _masked(log_so3(motion_a[..., :3, :3]), ok)
    beta = _masked(log_so3(motion_b[..., :3, :3]), ok)
    R_X = project_rotation((alpha[..., :, None] * beta[..., None, :]).sum(1))
    return _pose(R_X, _translation_from_pairs(motion_a, motion_b, ok, R_X))


def _kron(P: torch.Tensor, Q: torch.Tensor) -> torch.Tensor:
    """Batched Kronecker products :math:`(*, 9, 9)` of :math:`(*, 3, 3)` matrices (broadcast)."""
    out = torch.einsum("...ij,...kl->...ikjl", P, Q)
    return out.reshape(*out.shape[:-4], 9, 9)


def _null_vector(N: torch.Tensor) -> torch.Tensor:
    """The eigenvector of the smallest eigenvalue of symmetric :math:`(B, K, K)` matrices."""
    _, vecs = torch.linalg.eigh(0.5 * (N + N.transpose(-1, -2)))
    return vecs[..., 0]


def _rotation_from_vector(v: torch.Tensor) -> torch.Tensor:
    """A rotation from a scaled, signed row-major rotation :math:`(B, 9)` (the sign by the determinant)."""
    Rm = v.reshape(*v.shape[:-1], 3, 3)
    sign = torch.where(torch.linalg.det(Rm) < 0, -1.0, 1.0).to(v.dtype)
    return project_rotation(Rm * sign[..., None, None])


def andreff(A: torch.Tensor, M: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """``X`` :math:`(B, 4, 4)` by Andreff's linear (Kronecker) form on every pair of valid views (module doc;
    arguments as :func:`park_martin`)."""
    motion_a, motion_b, ok, _, _ = motion_pairs(A, M, valid)
    eye = torch.eye(3, dtype=A.dtype, device=A.device)
    Ra, Rb = motion_a[..., :3, :3], motion_b[..., :3, :3]
    # row-major vec: vec(R_A R_X) = (R_A kron I) vec(R_X), vec(R_X R_B) = (I kron R_B^T) vec(R_X)
    K = _kron(Ra, eye.expand_as(Ra)) - _kron(eye.expand_as(Rb), Rb.transpose(-1, -2))
    K = _masked(K, ok)
    R_X = _rotation_from_vector(_null_vector((K.transpose(-1, -2) @ K).sum(1)))
    return _pose(R_X, _translation_from_pairs(motion_a, motion_b, ok, R_X))


def robot_world(A: torch.Tensor, M: torch.Tensor, valid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``X`` and ``Z`` :math:`(B, 4, 4)` together from the absolute poses (module doc; arguments as
    :func:`park_martin`)."""
    eye = torch.eye(3, dtype=A.dtype, device=A.device)
    Ra, Rm = A[..., :3, :3], M[..., :3, :3]
    B, V = Ra.shape[:2]
    # vec(R_X R_M) = (I kron R_M^T) vec(R_X), vec(R_A R_Z) = (R_A kron I) vec(R_Z)
    left = _kron(eye.expand_as(Rm), Rm.transpose(-1, -2))
    right = _kron(Ra, eye.expand_as(Ra))
    K = _masked(torch.cat([left, -right], -1), valid)  # (B, V, 9, 18)
    v = _null_vector((K.transpose(-1, -2) @ K).sum(1))
    # one scale for both: det(R_X) = 1 (the sign by its determinant)
    scale = torch.linalg.det(v[:, :9].reshape(B, 3, 3))
    scale = scale.sign() * scale.abs().clamp_min(1e-300).pow(1.0 / 3.0)
    v = v / scale[:, None]
    R_X, R_Z = project_rotation(v[:, :9].reshape(B, 3, 3)), project_rotation(v[:, 9:].reshape(B, 3, 3))
    # t: [I, -R_A] (t_X, t_Z) = t_A - R_X t_M
    C = _masked(torch.cat([eye.expand(B, V, 3, 3), -Ra], -1), valid)  # (B, V, 3, 6)
    d = _masked(A[..., :3, 3] - (R_X[:, None] @ M[..., :3, 3:4])[..., 0], valid)
    t = (torch.linalg.pinv((C.transpose(-1, -2) @ C).sum(1)) @ (C.transpose(-1, -2) @ d[..., None]).sum(1))[..., 0]
    return _pose(R_X, t[:, :3]), _pose(R_Z, t[:, 3:])


def board_in_robot(A: torch.Tensor, M: torch.Tensor, valid: torch.Tensor, X: torch.Tensor) -> torch.Tensor:
    """The board's pose ``Z`` :math:`(B, 4, 4)` given ``X`` :math:`(B, 4, 4)`: the chordal mean of the views'
    ``A_v^{-1} X M_v`` (rotation: the sum projected on SO(3); translation: the mean)."""
    Zv = invert_transforms(A) @ X[:, None] @ M
    w = valid.to(A.dtype)
    R = project_rotation(_masked(Zv[..., :3, :3], valid).sum(1))
    t = _masked(Zv[..., :3, 3], valid).sum(1) / w.sum(1).clamp_min(1)[:, None]
    return _pose(R, t)


#: the closed forms the solver tries, by name (each ``(A, M, valid) -> X``)
CLOSED_FORMS = {
    "park_martin": park_martin,
    "andreff": andreff,
    "robot_world": lambda A, M, valid: robot_world(A, M, valid)[0],
}


def closed_form_candidates(A: torch.Tensor, M: torch.Tensor, valid: torch.Tensor
                           ) -> tuple[list[str], torch.Tensor, torch.Tensor]:
    """Every closed form of :data:`CLOSED_FORMS`: names, ``X`` and ``Z`` :math:`(B, K, 4, 4)` (non-finite results
    replaced by the identity: the caller ranks the candidates by their reprojection error)."""
    names, Xs, Zs = [], [], []
    for name, fn in CLOSED_FORMS.items():
        X = fn(A, M, valid)
        Z = board_in_robot(A, M, valid, X)
        eye = torch.eye(4, dtype=A.dtype, device=A.device)
        bad = ~(X.flatten(1).isfinite().all(-1) & Z.flatten(1).isfinite().all(-1))
        names.append(name)
        Xs.append(torch.where(bad[:, None, None], eye, X))
        Zs.append(torch.where(bad[:, None, None], eye, Z))
    return names, torch.stack(Xs, 1), torch.stack(Zs, 1)
