r"""The joint hand-eye fit as a least-squares *problem*: residuals, analytic normal equations and a retraction.

Unknowns per problem (batched over ``B`` problems): ``X`` and the board's pose ``Z`` (6 + 6, see
:mod:`~ccs_kornia.modules.hand_eye.setup`), optionally the camera's free intrinsics (``F`` coordinates of a
parameter basis, as :func:`~ccs_kornia.modules.calibration.lm.parameter_basis` gives them), optionally the board's
sag (mrcal's two coefficients ``c``, :mod:`~ccs_kornia.geometry.board_warp`: ``p`` then moves along the board's z by
``b(p) . c``) and, with a robot-pose noise term, one small 6-dof correction ``E_v`` of each view's robot pose. A board point ``p`` of view ``v`` is seen at

.. math::
    x_c = X^{-1} A_v' Z p, \qquad A_v' = E_v A_v \text{ (eye-in-hand)}, \quad A_v' = A_v E_v \text{ (eye-to-hand)}

(``E_v`` acts on the flange side of the chain either way) and the residual is its projection minus the observed
corner, weighted by the corner's inverse variance. The robot-pose noise term adds the prior residuals
``(log R_E / sigma_rot, t_E / sigma_trans)`` of every correction.

The normal equations have the arrow structure of the package's LM core
(:func:`~ccs_kornia.modules.calibration.schur_lm.schur_lm`): a *global* block
``G = 12 + F (+ 2)`` (``X``: rotation, translation; ``Z``: rotation, translation; the free intrinsics; the sag) and,
with the noise
term, one 6x6 block per view (``V = 0`` blocks without it), coupled to the global block only:
``(cost, U, g, W, Vb, gv)`` with ``U = J_g^T W J_g``, ``g = J_g^T W r``, ``W = J_g^T W J_v``, ``Vb = J_v^T W J_v``
(+ the prior), ``gv = J_v^T W r``. Rotations are updated multiplicatively on the left (``R <- exp(w) R``,
``t <- t + d``), so with ``q = R_Z p + t_Z``, ``s`` the point in the camera's robot frame and ``u = s - t_X``:

* ``d x_c / d w_X = R_X^T [u]_x``, ``d x_c / d t_X = -R_X^T``;
* ``d x_c / d w_Z = -R_X^T R' [R_Z p]_x``, ``d x_c / d t_Z = R_X^T R'`` (``R'`` the rotation of the chain
  from the board's frame to the camera's robot frame);
* ``d x_c / d c_k = R_X^T R' R_Z e_z b_k(p)`` (the sag);

each times the camera model's ``d uv / d x_c``.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from ccs_kornia.geometry.board_warp import board_warp_basis
from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.so3 import exp_so3, log_so3
from ccs_kornia.modules.hand_eye.setup import HandEyeSetup
from ccs_kornia.runtime.checks import check_tensor

__all__ = ["GLOBAL_POSE_PARAMS", "HandEyeProblem", "HandEyeState", "NormalEquations"]

#: global coordinates before the intrinsics: rotation and translation of ``X``, then of ``Z``
GLOBAL_POSE_PARAMS = 12


class HandEyeState(NamedTuple):
    """The unknowns of :class:`HandEyeProblem` (``B`` problems, ``V`` views, ``P`` camera parameters)."""

    RX: torch.Tensor  #: (B, 3, 3)
    tX: torch.Tensor  #: (B, 3)
    RZ: torch.Tensor  #: (B, 3, 3)
    tZ: torch.Tensor  #: (B, 3)
    params: torch.Tensor  #: (B, P) camera parameters (fixed ones included)
    RE: torch.Tensor  #: (B, V, 3, 3) robot-pose corrections (identity without the noise term)
    tE: torch.Tensor  #: (B, V, 3)
    warp: torch.Tensor  #: (B, 2) the board's sag (mrcal's ``calobject_warp``; held at 0 by a flat-board problem)

    def select(self, mask: torch.Tensor, other: "HandEyeState") -> "HandEyeState":
        """This state where ``mask`` :math:`(B,)` is True, ``other`` elsewhere."""
        return HandEyeState(*(torch.where(mask.view(-1, *([1] * (a.dim() - 1))), a, b) for a, b in zip(self, other)))


class NormalEquations(NamedTuple):
    """Arrow-structured normal equations of ``B`` problems (``G`` global coordinates, ``V`` item blocks of 6)."""

    cost: torch.Tensor  #: (B,) weighted sum of squared residuals (prior included)
    U: torch.Tensor  #: (B, G, G)
    g: torch.Tensor  #: (B, G) J^T W r of the global block
    W: torch.Tensor  #: (B, V, G, 6)
    Vb: torch.Tensor  #: (B, V, 6, 6)
    gv: torch.Tensor  #: (B, V, 6)

    def select(self, mask: torch.Tensor, other: "NormalEquations") -> "NormalEquations":
        return NormalEquations(*(torch.where(mask.view(-1, *([1] * (a.dim() - 1))), a, b) for a, b in zip(self, other)))


def _cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Cross products of broadcast (..., 3) vectors (elementwise: no small batched matrix products)."""
    a1, a2, a3 = a.unbind(-1)
    b1, b2, b3 = b.unbind(-1)
    return torch.stack([a2 * b3 - a3 * b2, a3 * b1 - a1 * b3, a1 * b2 - a2 * b1], -1)


def _times(rows: torch.Tensor, M: torch.Tensor) -> torch.Tensor:
    """Row vectors (..., K, 3) times broadcast 3x3 matrices (..., 3, 3), elementwise."""
    return sum(rows[..., k:k + 1] * M[..., k:k + 1, :] for k in range(3))


class HandEyeProblem:
    r"""The joint reprojection fit of ``B`` hand-eye problems (see the module doc).

    Args:
        setup: :class:`~ccs_kornia.modules.hand_eye.setup.HandEyeSetup`.
        model: the camera model.
        robot_poses: :math:`(B, V, 4, 4)` the flange's pose in the base frame per view (``x_base = T x_flange``).
        object_points: :math:`(N, 3)` or :math:`(B, N, 3)` the board's points.
        corners: :math:`(B, V, N, 2)` observed pixels (anything where the weight is 0).
        weights: :math:`(B, V, N)` inverse variances of the corners (0: unused).
        basis: :math:`(B, P, F)` the free intrinsics' basis (``None`` or ``F = 0``: intrinsics held).
        robot_noise: ``(sigma_rot, sigma_trans)`` of the robot's poses (radians, the poses' unit) for the noise
            term, one pair for all problems or :math:`(B, 2)`, or ``None`` (poses taken as exact).
        board_warp: estimate the board's sag (the state's ``warp``, two global coordinates after the intrinsics);
            ``False``: the board is flat (``warp`` ignored).

    Example:
        >>> from ccs_kornia.geometry.models import PINHOLE
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> T = torch.eye(4, dtype=torch.float64).expand(1, 3, 4, 4).clone()
        >>> T[0, :, :3, :3] = exp_so3(torch.tensor([[0.0, 0, 0], [0.3, 0, 0], [0, 0.3, 0.1]], dtype=torch.float64))
        >>> obj = board_object_points(3, 2, 0.05, dtype=torch.float64)
        >>> state = HandEyeProblem.initial_state(torch.eye(4, dtype=torch.float64)[None], torch.eye(4, dtype=torch.float64)[None],
        ...                                     torch.tensor([[500.0, 500.0, 320.0, 240.0]], dtype=torch.float64), 3)
        >>> state = state._replace(tZ=torch.tensor([[0.0, 0.0, 0.5]], dtype=torch.float64))
        >>> prob = HandEyeProblem("eye_to_hand", PINHOLE, T, obj, torch.zeros(1, 3, 6, 2, dtype=torch.float64),
        ...                       torch.ones(1, 3, 6, dtype=torch.float64))
        >>> eq = prob.normal_equations(state)
        >>> eq.U.shape, eq.W.shape
        (torch.Size([1, 12, 12]), torch.Size([1, 0, 12, 6]))
    """

    def __init__(
        self,
        setup: HandEyeSetup | str,
        model: CameraModel,
        robot_poses: torch.Tensor,
        object_points: torch.Tensor,
        corners: torch.Tensor,
        weights: torch.Tensor,
        basis: torch.Tensor | None = None,
        robot_noise: tuple[float, float] | torch.Tensor | None = None,
        board_warp: bool = False,
    ) -> None:
        self.setup = HandEyeSetup.parse(setup)
        self.model = model
        B, V, N = corners.shape[:3]
        check_tensor(robot_poses, "robot_poses", [B, V, 4, 4])
        check_tensor(weights, "weights", [B, V, N])
        dtype = robot_poses.dtype
        self.robot_poses = robot_poses
        self.A = self.setup.chain(robot_poses)
        obj = object_points.to(dtype)
        self.obj = obj.expand(B, N, 3) if obj.dim() == 2 else obj
        w = torch.where(corners.isfinite().all(-1), weights.to(dtype), 0.0).clamp_min(0)
        self.w = w
        self.obs = torch.where(w[..., None] > 0, corners.to(dtype), 0.0)
        self.basis = basis if basis is not None and basis.shape[-1] > 0 else None
        self.noise = None if robot_noise is None else \
            torch.as_tensor(robot_noise, dtype=dtype, device=corners.device).reshape(-1, 2).expand(B, 2)
        self.shape = (B, V, N)
        self.sag = board_warp_basis(self.obj) if board_warp else None  # (B, N, 2)

    def subset(self, index: torch.Tensor, weights: torch.Tensor | None = None) -> "HandEyeProblem":
        """The problems ``index`` :math:`(K,)` of the batch as a new problem, with other corner ``weights``
        :math:`(K, V, N)` if given (e.g. a view's zeroed to hold it out)."""
        w = self.w[index] if weights is None else weights
        return HandEyeProblem(self.setup, self.model, self.robot_poses[index], self.obj[index], self.obs[index], w,
                              None if self.basis is None else self.basis[index],
                              None if self.noise is None else self.noise[index], self.sag is not None)

    def reweighted(self, pixel_variance: torch.Tensor, robot_noise: torch.Tensor | None) -> "HandEyeProblem":
        """The same problems with every corner's variance times ``pixel_variance`` :math:`(B,)` and the noise term's
        sigmas ``robot_noise`` :math:`(B, 2)` (``None``: none)."""
        return HandEyeProblem(self.setup, self.model, self.robot_poses, self.obj, self.obs,
                              self.w / pixel_variance[:, None, None], self.basis, robot_noise, self.sag is not None)

    # -- sizes ---------------------------------------------------------------------------------------------------
    @property
    def num_intrinsics(self) -> int:
        """Free intrinsics ``F`` (coordinates after the 12 pose coordinates)."""
        return 0 if self.basis is None else self.basis.shape[-1]

    @property
    def num_global(self) -> int:
        """Global coordinates ``G``: 12 pose coordinates plus the free intrinsics, plus the sag's two."""
        return GLOBAL_POSE_PARAMS + self.num_intrinsics + (0 if self.sag is None else 2)

    @property
    def num_items(self) -> int:
        """6-dof blocks eliminated by the Schur complement: one per view with the noise term, else none."""
        return 0 if self.noise is None else self.shape[1]

    @property
    def num_residuals(self) -> torch.Tensor:
        """:math:`(B,)` scalar residuals: two per weighted corner, six per correction of a view with data with the
        noise term."""
        n = 2 * (self.w > 0).sum((1, 2))
        return n + (6 * (self.w > 0).any(-1).sum(-1) if self.noise is not None else 0)

    @staticmethod
    def initial_state(X: torch.Tensor, Z: torch.Tensor, params: torch.Tensor, views: int) -> HandEyeState:
        """A state from ``X``, ``Z`` :math:`(B, 4, 4)` and camera parameters :math:`(B, P)`, no corrections, a flat
        board."""
        B = X.shape[0]
        eye = torch.eye(3, dtype=X.dtype, device=X.device)
        return HandEyeState(X[:, :3, :3], X[:, :3, 3], Z[:, :3, :3], Z[:, :3, 3], params.to(X.dtype),
                            eye.expand(B, views, 3, 3), X.new_zeros(B, views, 3), X.new_zeros(B, 2))

    def board(self, s: HandEyeState) -> torch.Tensor:
        """The board's points :math:`(B, N, 3)` as the state has it (bent by its sag where the problem estimates
        one)."""
        if self.sag is None:
            return self.obj
        dz = (self.sag * s.warp[:, None, :]).sum(-1, keepdim=True)
        return torch.cat([self.obj[..., :2], self.obj[..., 2:] + dz], -1)

    # -- the model -------------------------------------------------------------------------------------------------
    def _chain(self, s: HandEyeState):
        """Board points in the camera's robot frame ``s`` :math:`(B, V, N, 3)`, ``q = R_Z p + t_Z`` :math:`(B, N, 3)`
        and the chain's rotation from the board's robot frame, with the correction's pieces."""
        RA, tA = self.A[..., :3, :3], self.A[..., :3, 3]
        q = self.board(s) @ s.RZ.transpose(-1, -2) + s.tZ[:, None]  # (B, N, 3)
        if self.setup is HandEyeSetup.EYE_IN_HAND:  # s = R_E (R_A q + t_A) + t_E
            s0 = q[:, None] @ RA.transpose(-1, -2) + tA[:, :, None]
            s_pt = s0 @ s.RE.transpose(-1, -2) + s.tE[:, :, None]
            R_chain = s.RE @ RA
            aux = s_pt - s.tE[:, :, None]  # R_E s0: d s / d w_E = -[R_E s0]_x
        else:  # s = R_A (R_E q + t_E) + t_A
            e = q[:, None] @ s.RE.transpose(-1, -2) + s.tE[:, :, None]
            s_pt = e @ RA.transpose(-1, -2) + tA[:, :, None]
            R_chain = RA @ s.RE
            aux = e - s.tE[:, :, None]  # R_E q: d s / d w_E = -R_A [R_E q]_x
        return s_pt, q, R_chain, aux

    def camera_points(self, s: HandEyeState) -> torch.Tensor:
        """Board points in the camera frame :math:`(B, V, N, 3)`."""
        s_pt = self._chain(s)[0]
        return (s_pt - s.tX[:, None, None]) @ s.RX[:, None]  # R_X^T (s - t_X), row vectors

    def residuals(self, s: HandEyeState) -> torch.Tensor:
        """Projections minus observations :math:`(B, V, N, 2)` (every corner, weighted or not)."""
        B, V, N = self.shape
        xc = self.camera_points(s)
        uv = self.model.columns(xc.reshape(B, V * N, 3), s.params, jacobians=False)[0]
        return uv.reshape(B, V, N, 2) - self.obs

    def _prior(self, s: HandEyeState) -> torch.Tensor:
        inv = self.prior_scale
        return torch.cat([log_so3(s.RE), s.tE], -1) * inv[:, None]  # (B, V, 6)

    @property
    def prior_scale(self) -> torch.Tensor:
        """:math:`(B, 6)` the noise term's ``1 / sigma`` per correction coordinate (rotation, translation)."""
        sr, st = self.noise[:, 0:1], self.noise[:, 1:2]
        return torch.cat([(1 / sr).expand(-1, 3), (1 / st).expand(-1, 3)], -1)

    def cost(self, s: HandEyeState) -> torch.Tensor:
        """:math:`(B,)` weighted sum of squared residuals (non-finite: infinity)."""
        r = torch.where(self.w[..., None] > 0, self.residuals(s), 0.0)
        c = (self.w[..., None] * r * r).sum((1, 2, 3))
        if self.noise is not None:
            c = c + (self._prior(s) ** 2).sum((1, 2))
        return torch.where(c.isfinite(), c, torch.full_like(c, float("inf")))

    def normal_equations(self, s: HandEyeState) -> NormalEquations:
        """The arrow-structured normal equations at ``s`` (module doc)."""
        B, V, N = self.shape
        s_pt, q, R_chain, aux = self._chain(s)
        u = s_pt - s.tX[:, None, None]
        xc = u @ s.RX[:, None]
        uv, dp, dX = self.model.columns(xc.reshape(B, V * N, 3), s.params)
        r = uv.reshape(B, V, N, 2) - self.obs
        on = self.w > 0
        r = torch.where(on[..., None], r, 0.0)
        # d uv / d s (robot frame) = (d uv / d x_c) R_X^T: (B, V, N, 2, 3); a row d times [v]_x is d x v
        Jx = torch.stack([d.expand(B, V * N, 2) for d in dX], -1).reshape(B, V, N, 2, 3)
        D = _times(Jx, s.RX.transpose(-1, -2)[:, None, None])
        cols = [_cross(D, u[..., None, :]), -D]
        DR = _times(D, R_chain[:, :, None])  # d uv / d q
        qz = (q - s.tZ[:, None])[:, None, :, None]  # R_Z p
        cols += [-_cross(DR, qz), DR]
        if self.basis is not None:
            Jp = torch.stack([d.expand(B, V * N, 2) for d in dp], -1).reshape(B, V, N, 2, -1)
            cols.append(Jp @ self.basis[:, None, None])
        if self.sag is not None:  # d uv / d c_k = (d uv / d q) R_Z e_z b_k(p)
            dz = (DR * s.RZ[:, None, None, None, :, 2]).sum(-1, keepdim=True)  # (B, V, N, 2, 1)
            cols.append(dz * self.sag[:, None, :, None, :])
        G = sum(c.shape[-1] for c in cols)
        if self.noise is not None:
            if self.setup is HandEyeSetup.EYE_IN_HAND:
                cols += [-_cross(D, aux[..., None, :]), D]
            else:
                DA = _times(D, self.A[..., :3, :3][:, :, None])
                cols += [-_cross(DA, aux[..., None, :]), DA]
        # one product per view gives every block: [J_g, J_v, r]^T W [J_g, J_v, r] (as the single-camera core does)
        A = torch.cat([*cols, r[..., None]], -1) * self.w.sqrt()[..., None, None]  # (B, V, N, 2, K)
        A = A.reshape(B, V, 2 * N, A.shape[-1])
        Gm = A.transpose(-1, -2) @ A  # (B, V, K, K)
        U, g = Gm[..., :G, :G].sum(1), Gm[..., :G, -1].sum(1)
        cost = Gm[..., -1, -1].sum(1)
        if self.noise is None:
            W = U.new_zeros(B, 0, G, 6)
            Vb = U.new_zeros(B, 0, 6, 6)
            gv = U.new_zeros(B, 0, 6)
        else:
            W, Vb, gv = Gm[..., :G, G:G + 6], Gm[..., G:G + 6, G:G + 6], Gm[..., G:G + 6, -1]
            inv = self.prior_scale[:, None]  # (B, 1, 6)
            prior = self._prior(s)
            Vb = Vb + torch.diag_embed(inv * inv).expand_as(Vb)
            gv = gv + prior * inv
            cost = cost + (prior ** 2).sum((1, 2))
        cost = torch.where(cost.isfinite(), cost, torch.full_like(cost, float("inf")))
        return NormalEquations(cost, U, g, W, Vb, gv)

    def retract(self, s: HandEyeState, dg: torch.Tensor, dv: torch.Tensor | None = None) -> HandEyeState:
        """The state moved by global increments ``dg`` :math:`(B, G)` and item increments ``dv`` :math:`(B, V, 6)`
        (rotations multiplied on the left by ``exp(w)``)."""
        params = s.params
        F = GLOBAL_POSE_PARAMS + self.num_intrinsics
        if self.basis is not None:
            params = params + (self.basis @ dg[:, GLOBAL_POSE_PARAMS:F, None])[..., 0]
        RE, tE = s.RE, s.tE
        if dv is not None and dv.shape[1]:
            RE, tE = exp_so3(dv[..., :3]) @ RE, tE + dv[..., 3:]
        warp = s.warp if self.sag is None else s.warp + dg[:, F:F + 2]
        return HandEyeState(exp_so3(dg[:, 0:3]) @ s.RX, s.tX + dg[:, 3:6], exp_so3(dg[:, 6:9]) @ s.RZ,
                            s.tZ + dg[:, 9:12], params, RE, tE, warp)
