r"""How much each view tells about a camera, and the views that lower its projection uncertainty most.

The solver's covariance of the camera parameters is :math:`\sigma^2 S^{-1}`, ``S`` the Schur complement of the board
poses in the normal equations (:mod:`~ccs_kornia.modules.calibration.schur_lm`). Each view's poses are its own, so
``S`` is a sum over the views of one small matrix each, the view's *information* :math:`M_v = H_{cc} - H_{cp}
H_{pp}^{-1} H_{pc}` (:func:`view_information`): the covariance of any subset of views is the inverse of the sum of
theirs. The projection uncertainty over the whole image (:mod:`~ccs_kornia.modules.calibration.quality.uncertainty`,
rotation fitted out as mrcal does) is then :math:`\sqrt{\operatorname{tr}(A \Sigma) / 2}` with ``A`` the mean of
:math:`J_g^T J_g` over a grid of pixels (:func:`image_information`), and :func:`greedy_information` adds, one at a
time, the view that lowers it most, until a view no longer helps.

Example:
    >>> from ccs_kornia.geometry.board_points import board_object_points
    >>> from ccs_kornia.geometry.camera import Camera
    >>> from ccs_kornia.geometry.models import K1K2
    >>> obj = board_object_points(6, 4, 0.03, dtype=torch.float64)
    >>> cam = Camera(K1K2, torch.tensor([500.0, 500, 320, 240, 0, 0], dtype=torch.float64), (640, 480))
    >>> rvec = torch.tensor([[[0.3, 0.0, 0.0], [0.0, 0.3, 0.0], [-0.3, 0.1, 0.0], [0.3, 0.0, 0.0]]], dtype=torch.float64)
    >>> tvec = torch.tensor([[[-0.08, -0.05, 0.5]]], dtype=torch.float64).expand(1, 4, 3)
    >>> M = view_information(cam, rvec, tvec, obj, torch.ones(1, 4, 24, dtype=torch.float64))
    >>> A = image_information(cam)
    >>> M.shape, A.shape
    (torch.Size([1, 4, 6, 6]), torch.Size([1, 6, 6]))
    >>> choice = greedy_information(M, A, max_count=3)  # the fourth view repeats the first
    >>> choice.order, choice.reason[3]
    ([2, 1, 0], 'cap')
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.calibration.quality.uncertainty import (
    image_points,
    image_rays,
    remove_rotation,
)
from ccs_kornia.runtime.checks import check_same_shape, check_tensor

__all__ = ["PRIOR", "GreedyChoice", "greedy_information", "image_information", "view_information"]

#: the information every camera starts from, per parameter, as a fraction of its average view's (in units where each
#: parameter's total information is 1): keeps the first choices defined while fewer views than parameters are taken
PRIOR = 1e-2


def view_information(
    camera: Camera,
    rvec: torch.Tensor,
    tvec: torch.Tensor,
    object_points: torch.Tensor,
    weights: torch.Tensor,
) -> torch.Tensor:
    r"""Each view's information about the camera parameters, its board pose eliminated (Schur complement).

    Args:
        camera: ``C`` cameras of one model (its parameters: ``fx, fy, cx, cy`` and the model's coefficients).
        rvec, tvec: :math:`(C, V, 3)` each view's board pose (world to camera, axis-angle), as the solver gives them.
        object_points: :math:`(N, 3)` or :math:`(C, N, 3)` the board's corners.
        weights: :math:`(C, V, N)` per-corner inverse variances (0: corner not used), as the solver's.

    Returns:
        :math:`(C, V, P, P)` float64 (zeros for a view without weighted corners); their sum over the views is the
        solver's information matrix at the same point.
    """
    m = camera.model
    check_tensor(rvec, "rvec", ["C", "V", "3"], C=len(camera))
    check_same_shape(tvec, "tvec", rvec, "rvec")
    check_tensor(weights, "weights", ["C", "V", "N"], C=rvec.shape[0], V=rvec.shape[1])
    C, _V, N = weights.shape
    rvec, tvec = rvec.double(), tvec.double()
    params = camera.params.double()
    obj = object_points.double().to(params.device)
    obj = obj.expand(C, N, 3) if obj.dim() == 2 else obj
    w = weights.double().nan_to_num(0.0).clamp_min(0.0)
    R = exp_so3(rvec)
    q = torch.einsum("cvij,cnj->cvni", R, obj)  # R X, (C, V, N, 3)
    uv, dp, dx = m.columns(q + tvec[:, :, None, :], params)
    shape = uv.shape
    qx, qy, qz = q[..., 0:1], q[..., 1:2], q[..., 2:3]
    dxx, dxy, dxz = dx
    # rotation R <- exp(w) R: d uv / d w = q x (d uv / d Xc), as the solver's
    cols = [c.expand(shape) for c in dp] + [(qy * dxz - qz * dxy).expand(shape), (qz * dxx - qx * dxz).expand(shape),
                                             (qx * dxy - qy * dxx).expand(shape), dxx.expand(shape),
                                             dxy.expand(shape), dxz.expand(shape)]
    J = torch.stack(cols, -1)  # (C, V, N, 2, P + 6)
    good = (w > 0) & J.isfinite().flatten(-2).all(-1)
    J = torch.where(good[..., None, None], J, torch.zeros_like(J))
    sw = torch.where(good, w, torch.zeros_like(w)).sqrt()[..., None, None]
    J = (J * sw).flatten(2, 3)  # (C, V, 2N, P + 6)
    H = J.transpose(-1, -2) @ J
    P = m.num_params
    Hcc, Hcp, Hpp = H[..., :P, :P], H[..., :P, P:], H[..., P:, P:]
    eye = torch.eye(6, dtype=H.dtype, device=H.device)
    scale = Hpp.diagonal(dim1=-2, dim2=-1).amax(-1).clamp_min(1e-300)[..., None, None]
    solved = torch.linalg.solve(Hpp + 1e-12 * scale * eye, Hcp.transpose(-1, -2))
    M = Hcc - Hcp @ solved
    M = 0.5 * (M + M.transpose(-1, -2))
    return torch.where(good.any(-1)[..., None, None] & M.isfinite().flatten(-2).all(-1)[..., None, None], M,
                       torch.zeros_like(M))


def image_information(
    camera: Camera,
    image_size: tuple[int, int] | None = None,
    grid: tuple[int, int] = (16, 12),
    compensate_rotation: bool = True,
) -> torch.Tensor:
    r"""The mean over a grid of pixels of :math:`J^T J`, ``J`` the derivative of the projection of each pixel's ray by
    the camera parameters: :math:`\operatorname{tr}(A \Sigma) / 2` is the mean squared projection uncertainty over the
    image (both directions) of a camera with covariance :math:`\Sigma`.

    Args:
        camera: ``C`` cameras of one model.
        image_size: ``(W, H)`` (default: the cameras').
        grid: ``(across, down)`` pixels, the image's corners included.
        compensate_rotation: fit out the camera rotation that the boards' poses absorb, as
            :func:`~ccs_kornia.modules.calibration.quality.uncertainty.projection_uncertainty` does.

    Returns:
        :math:`(C, P, P)` float64 (pixels where the model has no inverse are left out).

    Example:
        >>> from ccs_kornia.geometry.models import PINHOLE
        >>> cam = Camera(PINHOLE, torch.tensor([500.0, 500, 320, 240], dtype=torch.float64), (640, 480))
        >>> A = image_information(cam, compensate_rotation=False)
        >>> [round(float(x), 3) for x in A[0].diagonal()[2:]]  # a principal-point shift moves every pixel alike
        [1.0, 1.0]
    """
    camera = camera.to(dtype=torch.float64)
    pixels = image_points(image_size or camera.image_size, grid, dtype=camera.dtype).to(camera.device)
    rays = image_rays(camera, pixels)
    ok = rays.isfinite().all(-1)  # (C, G)
    safe = rays.nan_to_num(0.0)
    _, J, Jx = camera.project(safe, jacobians=True)  # the derivatives by the model's own parameters
    if compensate_rotation:
        A = torch.linalg.cross(safe[..., None, :].expand_as(Jx), Jx, dim=-1)  # d pixel / d camera rotation
        J = remove_rotation(J, torch.where(ok[..., None, None], A, torch.full_like(A, float("nan"))), ok)
    J = torch.where(ok[..., None, None], J.nan_to_num(0.0), torch.zeros_like(J)).flatten(1, 2)  # (C, 2G, P)
    return (J.transpose(-1, -2) @ J) / ok.sum(-1).clamp_min(1)[:, None, None]


@dataclass
class GreedyChoice:
    """What :func:`greedy_information` chose.

    Attributes:
        order: the units (views, or a rig's instants) taken, in the order taken.
        gains: each one's gain when taken (see :func:`greedy_information`).
        uncertainty: :math:`(C, T + 1)` each camera's predicted RMS projection uncertainty over the image (both
            directions) for corners of unit standard deviation per coordinate (multiply by the residuals' for
            pixels), before the first unit and after each.
        reason: per unit, ``""`` (taken), ``"unavailable"``, ``"copy"`` (a near copy of ``copy_of``), ``"adds
            nothing"`` (its gain fell below ``min_gain``) or ``"cap"`` (``max_count`` taken before it).
        copy_of: per unit, the unit taken that it copies (-1: none).
        gain: per unit, its gain when the choice stopped or when taken (``nan``: never judged).
    """

    order: list[int]
    gains: list[float]
    uncertainty: torch.Tensor
    reason: list[str]
    copy_of: list[int]
    gain: list[float] = field(default_factory=list)


def greedy_information(
    information: torch.Tensor,
    image: torch.Tensor,
    available: torch.Tensor | None = None,
    conflicts: torch.Tensor | None = None,
    max_count: int | None = None,
    min_gain: float = 0.0,
    links: bool = False,
    prior: float = PRIOR,
    link_weights: torch.Tensor | None = None,
    copies_last: bool = False,
) -> GreedyChoice:
    r"""Take units (views, or a rig's instants) one at a time, each time the one that lowers the cameras' predicted
    projection uncertainty most, until none lowers it by ``min_gain`` or ``max_count`` are taken.

    A unit's *gain* is, summed over the cameras that see it, the relative drop of the camera's RMS projection
    uncertainty over the image, :math:`1 - U(S \cup \{v\}) / U(S)` with :math:`U(S)^2 \propto \operatorname{tr}(A
    (H_0 + \sum_S M)^{-1})`; with ``links``, plus for every pair of cameras that see it together the relative drop of
    :math:`1/\sqrt{n}` for the ``n`` units the pair shares (a rig's relative poses rest on the frames its cameras see
    together). Equally informative units give a gain of about :math:`1 / (2 |S|)`: ``min_gain = 0.01`` stops near
    50 of them, fewer where the later ones repeat poses already taken, more where they add new ones.

    Args:
        information: :math:`(C, V, P, P)` each unit's information per camera (:func:`view_information`; zeros where
            the camera does not see the unit).
        image: :math:`(C, P, P)` (:func:`image_information`).
        available: :math:`(V,)` bool, the units that may be taken (default: those any camera sees).
        conflicts: :math:`(V, V)` bool, unit ``v`` is a near copy of unit ``u``: taking ``u`` rules ``v`` out.
        max_count: units taken at most (``None``: no cap).
        min_gain: the gain below which a unit adds nothing.
        links: add the cameras' shared units to the gain (rigs).
        prior: :data:`PRIOR`.
        link_weights: :math:`(C, V)` how much each camera's view of a unit counts toward a link (the smaller of the
            pair's; default 1).
        copies_last: a near copy waits instead of being ruled out: once no other unit is left (or adds
            ``min_gain``), the copies are judged like any unit, up to ``max_count`` (a copy not taken keeps the reason
            ``"copy"``). A copy of a still board is another measurement of the same pose: its noise averages, where a
            new pose would have added more.

    Returns:
        :class:`GreedyChoice`.
    """
    check_tensor(information, "information", ["C", "V", "P", "P"], P=information.shape[-1])
    check_tensor(image, "image", ["C", "P", "P"], C=information.shape[0], P=information.shape[-1])
    if max_count is not None and max_count < 1:
        raise ValueError(f"max_count must be >= 1, got {max_count}.")
    M = information.double()
    C, V, P, _ = M.shape
    seen = M.diagonal(dim1=-2, dim2=-1).abs().sum(-1) > 0  # (C, V)
    avail = seen.any(0) if available is None else available.bool().to(M.device) & seen.any(0)
    # each camera's parameters scaled to a total information of 1 (the coefficients and the focal lengths differ by
    # orders of magnitude); the prior a fraction of an average view's
    total = torch.where((seen & avail)[..., None, None], M, torch.zeros_like(M)).sum(1).diagonal(dim1=-2, dim2=-1)
    d = total.clamp_min(1e-300).rsqrt()  # (C, P)
    Ms = M * d[:, None, :, None] * d[:, None, None, :]
    A = image.double() * d[:, :, None] * d[:, None, :]
    views = (seen & avail).sum(1).clamp_min(1).to(M.dtype)
    H = (prior / views)[:, None, None] * torch.eye(P, dtype=M.dtype, device=M.device)

    def spread(Hs: torch.Tensor) -> torch.Tensor:  # U^2 up to the residual's variance
        return (A[:, None] if Hs.dim() == 4 else A).mul(torch.linalg.inv(Hs).transpose(-1, -2)).sum((-1, -2))

    u2 = spread(H)
    history = [(0.5 * u2).clamp_min(0).sqrt()]
    pairs = [(a, b) for a in range(C) for b in range(a + 1, C)] if links else []
    shared = {p: 0 for p in pairs}
    reason = ["" if bool(avail[v]) else "unavailable" for v in range(V)]
    copy_of = [-1] * V
    gain_of = [float("nan")] * V
    open_ = avail.clone()
    waiting = torch.zeros_like(open_)  # near copies put off (copies_last)
    order: list[int] = []
    gains: list[float] = []

    def reopen() -> bool:  # the copies' turn: judged like any unit from now on
        nonlocal conflicts
        if not bool(waiting.any()):
            return False
        open_.copy_(open_ | waiting)
        waiting.zero_()
        conflicts = None
        return True

    while bool(open_.any()) or reopen():
        if max_count is not None and len(order) >= max_count:
            for v in open_.nonzero().flatten().tolist():
                if copy_of[v] < 0:
                    reason[v] = "cap"
            break
        cand = open_.nonzero().flatten()
        trial = spread(H[:, None] + Ms[:, cand])  # (C, K)
        drop = 1.0 - (trial.clamp_min(0) / u2.clamp_min(1e-300)[:, None]).sqrt()
        gain = torch.where(seen[:, cand], drop, torch.zeros_like(drop)).sum(0)
        for a, b in pairs:
            both = (seen[a, cand] & seen[b, cand]).to(gain.dtype)
            if link_weights is not None:
                both = both * torch.minimum(link_weights[a, cand], link_weights[b, cand]).to(gain)
            n = shared[(a, b)]
            gain = gain + both * (1.0 - (n / (n + 1.0)) ** 0.5)
        for k, v in enumerate(cand.tolist()):
            gain_of[v] = float(gain[k])
        best = int(torch.argmax(gain))
        if not float(gain[best]) >= min_gain:
            if reopen():
                continue
            for v in cand.tolist():
                if copy_of[v] < 0:
                    reason[v] = "adds nothing"
            break
        v = int(cand[best])
        reason[v], copy_of[v] = "", -1
        order.append(v)
        gains.append(float(gain[best]))
        open_[v] = False
        H = H + Ms[:, v]
        u2 = spread(H)
        history.append((0.5 * u2).clamp_min(0).sqrt())
        for a, b in pairs:
            if bool(seen[a, v] & seen[b, v]):
                shared[(a, b)] += 1
        if conflicts is not None:
            for u in (conflicts[:, v].to(open_.device) & open_).nonzero().flatten().tolist():
                open_[u] = False
                reason[u], copy_of[u] = "copy", v
                if copies_last:
                    waiting[u] = True
    return GreedyChoice(order, gains, torch.stack(history, -1), reason, copy_of, gain_of)
