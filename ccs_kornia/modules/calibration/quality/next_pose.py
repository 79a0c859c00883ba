r"""The next board pose to show a camera: the one that lowers its predicted projection uncertainty most.

A calibration's information about the camera parameters is the sum of its views' (the Schur complement of each
view's board pose: :func:`~ccs_kornia.modules.calibration.quality.view_information.view_information`), and the
covariance of the parameters :math:`\sigma^2 H^{-1}`. A board held at a new pose adds that pose's information
:math:`M`, whatever the corners it will show, so the uncertainty the calibration *would* have after it,
:math:`\sigma^2 (H + M)^{-1}` propagated through the projection of every pixel's ray
(:mod:`~ccs_kornia.modules.calibration.quality.uncertainty`, the camera rotation fitted out as mrcal does), is known
before it is shown. :func:`candidate_poses` lays out the poses a hand-held board reaches (its centre over a grid of
the image, a few distances, tilted about both axes, at least three quarters of its corners inside the image: a board
partly beyond the image's edge reaches its corners, :data:`MIN_SEEN`), :func:`worst_uncertainty` is the figure that
decides when a capture is done (the worst 1-sigma projection uncertainty over the image, px), and
:func:`next_poses` ranks the candidates by the fourth-power mean of the 1-sigma over the image (:data:`RANK_POWER`):
between the RMS (the error to expect over the whole image) and the worst, it weighs the worst pixels most without
chasing the one pixel that is worst now; ranked by the worst, the guided person needed more frames on normal lenses,
by the RMS more on wide ones (docs/capture.md). The mean is taken over the pixels whose rays point in front of the
camera: a fisheye's image corners beyond 90 degrees are where no board can be seen, their uncertainty is the model's
extrapolation, and a mean that weighs the worst pixels most would chase them. :func:`pose_instruction` says the best in one line ("top left, closer, top edge tilted about 30
degrees away"); :class:`NextBestPose` is the module form. Nothing here needs an image or a page: a camera and its
information in, ranked poses out.

Example:
    >>> from ccs_kornia.geometry.board_points import board_object_points
    >>> from ccs_kornia.geometry.models import K1K2
    >>> obj = board_object_points(9, 6, 0.03, dtype=torch.float64)
    >>> cam = Camera(K1K2, torch.tensor([600.0, 600, 320, 240, 0, 0], dtype=torch.float64), (640, 480))
    >>> rvec = torch.zeros(1, 1, 3, dtype=torch.float64)  # one view so far: flat, at the image centre
    >>> tvec = torch.tensor([[[-0.12, -0.075, 0.6]]], dtype=torch.float64)
    >>> H = view_information(cam, rvec, tvec, obj, torch.ones(1, 1, 54, dtype=torch.float64)).sum(1)
    >>> best = next_poses(cam, H, obj, sigma=0.2)
    >>> bool(best.worst_px[0] < best.current_px), bool(best.tilt_deg[0].abs().max() > 0)  # a tilted board helps
    (True, True)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.so3 import exp_so3, log_so3
from ccs_kornia.modules.calibration.quality.uncertainty import (
    image_points,
    image_rays,
    remove_rotation,
)
from ccs_kornia.modules.calibration.quality.view_information import view_information
from ccs_kornia.runtime.checks import check_tensor

__all__ = [
    "DISTANCES",
    "MAX_TILT_DEG",
    "MIN_SEEN",
    "POSITIONS",
    "RANK_POWER",
    "TILTS_DEG",
    "CandidatePoses",
    "NextBestPose",
    "PoseSuggestion",
    "candidate_poses",
    "next_poses",
    "place_board",
    "pose_instruction",
    "uncertainty_map",
    "worst_uncertainty",
]

#: the board centre's positions over the image, ``(across, down)``: a grid from 10 % to 90 % of each side (a pose
#: whose board leaves the image is left out)
POSITIONS = (5, 5)
#: the distances tried, as the fraction of the image width the untilted board spans at the image centre
DISTANCES = (0.3, 0.45, 0.65)
#: the tilts tried about each axis (degrees)
TILTS_DEG = (-40.0, -20.0, 0.0, 20.0, 40.0)
#: a hand-held board is not turned further than this from facing the camera (degrees, both axes together)
MAX_TILT_DEG = 50.0
#: the fraction of the board's corners a candidate pose shows inside the image at least (1: the whole board): a board
#: partly beyond the image's edge reaches its corners and edges, where a whole board cannot; the corners outside add
#: nothing to its information (the detectors take partial boards)
MIN_SEEN = 0.75
#: the information every parameter starts from, as a fraction of an average candidate's: keeps the first choices
#: defined while no view is taken
PRIOR = 1e-2
#: the power mean of the 1-sigma over the image that ranks the candidate poses (2: the RMS; large: the worst)
RANK_POWER = 4


@dataclass
class CandidatePoses:
    """Board poses a camera could be shown (:func:`candidate_poses`).

    Attributes:
        rvec, tvec: :math:`(K, 3)` each the board's pose (board to camera, axis-angle), as the solver's.
        position: :math:`(K, 2)` where the board's centre is, as fractions of the image ``(x, y)`` (0: left / top).
        fill: :math:`(K,)` the fraction of the image width the untilted board spans at the image centre.
        tilt_deg: :math:`(K, 2)` the turn about the camera's x axis (positive: the bottom edge away) and its y axis
            (positive: the left edge away), degrees.
        outline: :math:`(K, 4, 2)` where the board's four extreme corners project (first, end of the first row, last,
            start of the last row), px.
        seen: :math:`(K, N)` bool, the corners inside the image (``None``: all).
    """

    rvec: torch.Tensor
    tvec: torch.Tensor
    position: torch.Tensor
    fill: torch.Tensor
    tilt_deg: torch.Tensor
    outline: torch.Tensor
    seen: torch.Tensor | None = None

    def __len__(self) -> int:
        return int(self.rvec.shape[0])

    def take(self, index: torch.Tensor) -> CandidatePoses:
        """The candidates at ``index`` (a long index or a bool mask)."""
        return CandidatePoses(*(getattr(self, f)[index] for f in
                                ("rvec", "tvec", "position", "fill", "tilt_deg", "outline")),
                              seen=None if self.seen is None else self.seen[index])


def _board_frame(object_points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, float]:
    """The board's points about their centre, the centre, and the board's width (its x extent)."""
    centre = object_points.mean(0, keepdim=True)
    centred = object_points - centre
    return centred, centre[0], float(centred[:, 0].amax() - centred[:, 0].amin())


def place_board(
    camera: Camera,
    object_points: torch.Tensor,
    pixels: torch.Tensor,
    fill: torch.Tensor,
    tilt_deg: torch.Tensor,
    roll_deg: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    r"""Board poses from where a person holds the board: its centre on the ray of ``pixels``, at the distance where
    the untilted board spans ``fill`` of the image width (at the camera's focal length), turned about the camera's x
    and y axes (``tilt_deg``: positive turns the bottom edge / the left edge away) and about its own normal
    (``roll_deg``).

    Args:
        camera: one camera with its image size.
        object_points: :math:`(N, 3)` the board's corners (``z = 0``).
        pixels: :math:`(K, 2)`; fill: :math:`(K,)`; tilt_deg: :math:`(K, 2)`; roll_deg: :math:`(K,)` or ``None``.

    Returns:
        ``rvec, tvec`` :math:`(K, 3)` (the pose of ``object_points`` as given, board to camera) and the corners'
        projections :math:`(K, N, 2)` and depths :math:`(K, N)`.

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.models import PINHOLE
        >>> cam = Camera(PINHOLE, torch.tensor([600.0, 600, 320, 240], dtype=torch.float64), (640, 480))
        >>> obj = board_object_points(9, 6, 0.03, dtype=torch.float64)
        >>> _, _, uv, _ = place_board(cam, obj, torch.tensor([[320.0, 240.0]], dtype=torch.float64),
        ...                           torch.tensor([0.5], dtype=torch.float64), torch.zeros(1, 2, dtype=torch.float64))
        >>> round(float(uv[0, :, 0].amax() - uv[0, :, 0].amin()))  # half of 640
        320
    """
    check_tensor(pixels, "pixels", ["K", "2"])
    check_tensor(tilt_deg, "tilt_deg", ["K", "2"], K=pixels.shape[0])
    camera = camera.to(dtype=torch.float64)
    dev = camera.device
    W = camera.image_size[0]
    obj, middle, width = _board_frame(object_points.double().to(dev))
    if not width > 0:
        raise ValueError("object_points span no width.")
    px, fill, rad = pixels.double().to(dev), fill.double().to(dev), torch.deg2rad(tilt_deg.double().to(dev))
    rays = camera.unproject(px[None])[0]
    rays = rays / rays.norm(dim=-1, keepdim=True)
    zero = torch.zeros_like(rad[:, 0])
    R = exp_so3(torch.stack([rad[:, 0], zero, zero], -1)) @ exp_so3(torch.stack([zero, rad[:, 1], zero], -1))
    if roll_deg is not None:
        R = R @ exp_so3(torch.stack([zero, zero, torch.deg2rad(roll_deg.double().to(dev))], -1))
    centre = rays * (float(camera.params[0, 0]) * width / (fill * W))[:, None]
    pts = torch.einsum("kij,nj->kni", R, obj) + centre[:, None, :]  # (K, N, 3)
    uv = camera.project(pts.reshape(1, -1, 3))[0].reshape(pts.shape[0], -1, 2)
    # the pose of the board's own points: R (X - c) + t = R X + (t - R c)
    return log_so3(R), centre - R @ middle, uv, pts[..., 2]


def candidate_poses(
    camera: Camera,
    object_points: torch.Tensor,
    board_size: tuple[int, int] | None = None,
    positions: tuple[int, int] = POSITIONS,
    distances: tuple[float, ...] = DISTANCES,
    tilts_deg: tuple[float, ...] = TILTS_DEG,
    max_tilt_deg: float = MAX_TILT_DEG,
    margin: float = 0.02,
    min_seen: float | None = None,
) -> CandidatePoses:
    r"""The board poses a hand-held board reaches in front of one camera, at least :data:`MIN_SEEN` of its corners
    inside the image.

    The board's centre is put on the ray of each of a grid of pixels (``positions``, spanning the image), at the
    distance where the untilted board spans each fraction ``distances`` of the image width, and turned by each pair
    of ``tilts_deg`` about the camera's x and y axes whose total turn is at most ``max_tilt_deg``
    (:func:`place_board`). A corner is seen where it lies inside the image less ``margin`` of its size on each side;
    poses that show fewer than ``min_seen`` of the corners, or with a corner behind the camera, are left out. A board
    partly beyond the image's edge puts its seen corners where a whole board cannot reach (the image's corners and
    edges, where the distortion is least known); its information counts the seen corners only (``seen``).

    Args:
        camera: one camera with its image size.
        object_points: :math:`(N, 3)` the board's corners (``z = 0``), grid order.
        board_size: ``(cols, rows)`` inner corners, for the outline (default: a single row of ``N``).
        positions, distances, tilts_deg, max_tilt_deg: :data:`POSITIONS`, :data:`DISTANCES`, :data:`TILTS_DEG`,
            :data:`MAX_TILT_DEG`.
        margin: the fraction of the image kept clear on each side.
        min_seen: the fraction of the corners a pose shows at least (default :data:`MIN_SEEN`; 1: the whole board).

    Returns:
        :class:`CandidatePoses` (float64, on the camera's device).

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.models import PINHOLE
        >>> cam = Camera(PINHOLE, torch.tensor([600.0, 600, 320, 240], dtype=torch.float64), (640, 480))
        >>> poses = candidate_poses(cam, board_object_points(9, 6, 0.03, dtype=torch.float64), (9, 6))
        >>> len(poses) > 100, poses.outline.shape[1:]
        (True, torch.Size([4, 2]))
    """
    if len(camera) != 1 or camera.image_size is None:
        raise ValueError(f"candidate_poses takes one camera with its image size, got {len(camera)}.")
    check_tensor(object_points, "object_points", ["N", "3"])
    camera = camera.to(dtype=torch.float64)
    dev, f64 = camera.device, torch.float64
    W, H = camera.image_size
    n = object_points.shape[0]
    cols, rows = board_size if board_size is not None else (n, 1)
    ends = torch.tensor([0, cols - 1, cols * rows - 1, cols * (rows - 1)], device=dev)
    grid = torch.stack(torch.meshgrid(torch.linspace(0.1 * W, 0.9 * W, positions[0], dtype=f64, device=dev),
                                      torch.linspace(0.1 * H, 0.9 * H, positions[1], dtype=f64, device=dev),
                                      indexing="xy"), -1).reshape(-1, 2)
    tilts = torch.tensor([(a, b) for a in tilts_deg for b in tilts_deg if math.hypot(a, b) <= max_tilt_deg + 1e-9],
                         dtype=f64, device=dev)  # (T, 2)
    fills = torch.tensor(distances, dtype=f64, device=dev)
    G, D, T = grid.shape[0], fills.shape[0], tilts.shape[0]
    px = grid[:, None, None].expand(G, D, T, 2).reshape(-1, 2)
    fill = fills[None, :, None].expand(G, D, T).reshape(-1)
    tilt = tilts[None, None].expand(G, D, T, 2).reshape(-1, 2)
    rvec, tvec, uv, depth = place_board(camera, object_points, px, fill, tilt)
    mx, my = margin * W, margin * H
    seen = ((uv[..., 0] >= mx) & (uv[..., 0] <= W - 1 - mx) & (uv[..., 1] >= my) & (uv[..., 1] <= H - 1 - my)
            & uv.isfinite().all(-1))
    min_seen = MIN_SEEN if min_seen is None else min_seen
    keep = (depth > 0).all(-1) & (seen.double().mean(-1) >= min_seen - 1e-9)
    position = px / torch.tensor([W, H], dtype=f64, device=dev)
    return CandidatePoses(rvec, tvec, position, fill, tilt, uv[:, ends], seen).take(keep)


#: the last cameras' pixel derivatives (a live capture asks for the same camera's figure many times between solves)
_JACOBIANS: dict = {}
#: entries each store keeps: two per camera in the candidates' store, for a rig's or a batch's cameras asked in turn
_REMEMBERED = 32
#: the last cameras' candidate poses and each candidate's information (the same, for the ranking)
_CANDIDATES: dict = {}


def _camera_key(camera: Camera) -> tuple:
    return (str(camera.model), tuple(camera.params.flatten().tolist()), tuple(camera.image_size), str(camera.device))


def _remembered(store: dict, key: tuple, make):
    """``store[key]``, made by ``make()`` when missing; the store keeps the last :data:`_REMEMBERED`."""
    if key not in store:
        if len(store) >= _REMEMBERED:
            store.pop(next(iter(store)))
        store[key] = make()
    return store[key]


def _tensor_key(x: torch.Tensor) -> tuple:
    return tuple(x.shape), x.detach().double().cpu().numpy().tobytes()


def _candidates_and_information(camera: Camera, object_points: torch.Tensor, board_size: tuple[int, int] | None,
                                candidates: CandidatePoses | None,
                                min_seen: float | None = None) -> tuple[CandidatePoses, torch.Tensor]:
    """The candidate poses (:func:`candidate_poses` where none are given) and each one's information :math:`(K, P,
    P)`, remembered for the last few cameras."""
    obj = object_points.double().to(camera.device)
    if candidates is None:
        min_seen = MIN_SEEN if min_seen is None else float(min_seen)
        candidates = _remembered(_CANDIDATES, ("poses", _camera_key(camera), _tensor_key(obj), board_size, min_seen),
                                 lambda: candidate_poses(camera, obj, board_size, min_seen=min_seen))
    poses = candidates

    def information() -> torch.Tensor:
        seen = (torch.ones(len(poses), obj.shape[0], dtype=torch.bool, device=camera.device) if poses.seen is None
                else poses.seen)
        return view_information(camera, poses.rvec[None], poses.tvec[None], obj, seen[None].double())[0]

    key = ("information", _camera_key(camera), _tensor_key(obj), _tensor_key(poses.rvec), _tensor_key(poses.tvec),
           None if poses.seen is None else _tensor_key(poses.seen))
    return poses, _remembered(_CANDIDATES, key, information)


def _pixel_jacobians(camera: Camera, grid: tuple[int, int]) -> tuple[torch.Tensor, ...]:
    """d pixel / d the model's parameters :math:`(G, 2, P)` at a grid of pixels, the camera rotation fitted out; the
    pixels :math:`(G, 2)`, where the model has an inverse :math:`(G,)` and where its ray points in front of the camera
    :math:`(G,)` (remembered for the last few cameras)."""
    return _remembered(_JACOBIANS, (*_camera_key(camera), tuple(grid)), lambda: _compute_pixel_jacobians(camera, grid))


def _compute_pixel_jacobians(camera: Camera, grid: tuple[int, int]) -> tuple[torch.Tensor, ...]:
    pixels = image_points(camera.image_size, grid, dtype=camera.dtype).to(camera.device)
    rays = image_rays(camera, pixels)
    ok = rays.isfinite().all(-1)
    safe = rays.nan_to_num(0.0)
    _, J, Jx = camera.project(safe, jacobians=True)
    A = torch.linalg.cross(safe[..., None, :].expand_as(Jx), Jx, dim=-1)
    J = remove_rotation(J, torch.where(ok[..., None, None], A, torch.full_like(A, float("nan"))), ok)
    J = torch.where(ok[..., None, None], J.nan_to_num(0.0), torch.zeros_like(J))
    return J[0, ..., : camera.model.num_params], pixels, ok[0], ok[0] & (safe[0, :, 2] > 0)


def _regularised(information: torch.Tensor, typical: torch.Tensor, prior: float) -> torch.Tensor:
    """``information`` plus ``prior`` times the diagonal of ``typical`` (an average view's): defined with no view."""
    diag = typical.diagonal(dim1=-2, dim2=-1).clamp_min(1e-300)
    return information + prior * torch.diag_embed(diag)


def uncertainty_map(
    camera: Camera,
    information: torch.Tensor,
    sigma: float = 1.0,
    grid: tuple[int, int] = (16, 12),
    typical: torch.Tensor | None = None,
    prior: float = PRIOR,
) -> torch.Tensor:
    r"""The worst-direction 1-sigma projection uncertainty (px) at a grid of pixels, for one or several information
    matrices of one camera (the camera rotation fitted out, as mrcal does).

    Args:
        camera: one camera with its image size.
        information: :math:`(*, P, P)` in the model's parameters (:func:`view_information` summed over views), in the
            units of corner weights ``1 / sigma^2``.
        sigma: the corners' standard deviation (px) at weight 1 (the solver's residual RMS).
        grid: ``(across, down)`` pixels, the image's corners included.
        typical: :math:`(P, P)` an average view's information, scaling the prior (default: ``information``'s own
            diagonal over the leading dimensions).
        prior: the prior's fraction of ``typical``.

    Returns:
        :math:`(*, down, across)` px; NaN where the model has no inverse.

    Example:
        >>> from ccs_kornia.geometry.models import PINHOLE
        >>> cam = Camera(PINHOLE, torch.tensor([500.0, 500, 320, 240], dtype=torch.float64), (640, 480))
        >>> uncertainty_map(cam, torch.eye(4, dtype=torch.float64) * 1e4, prior=0.0).shape
        torch.Size([12, 16])
    """
    camera = camera.to(dtype=torch.float64)
    J, _, ok, _ = _pixel_jacobians(camera, grid)
    info = information.double().to(camera.device)
    if typical is None:
        typical = info.reshape(-1, *info.shape[-2:]).mean(0)
    cov = sigma ** 2 * torch.linalg.pinv(_regularised(info, typical.double(), prior), hermitian=True)
    # J cov J^T per pixel as one product: the pixels' outer products J_i J_j^T flattened, (*, G, 2, 2)
    G, _, P = J.shape
    outer = (J[:, :, None, :, None] * J[:, None, :, None, :]).reshape(G * 4, P * P)
    S = (cov.reshape(*cov.shape[:-2], P * P) @ outer.T).reshape(*cov.shape[:-2], G, 2, 2)
    a, b, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 1]
    lam = ((a + d) / 2 + (((a - d) / 2) ** 2 + b * b).sqrt()).clamp_min(0).sqrt()
    lam = torch.where(ok, lam, torch.full_like(lam, float("nan")))
    return lam.unflatten(-1, (grid[1], grid[0]))


def worst_uncertainty(camera: Camera, information: torch.Tensor, sigma: float = 1.0,
                      grid: tuple[int, int] = (16, 12), typical: torch.Tensor | None = None,
                      prior: float = PRIOR) -> torch.Tensor:
    r"""The figure that decides: the worst 1-sigma projection uncertainty over the image (px), :math:`(*)` for
    information :math:`(*, P, P)` (see :func:`uncertainty_map`)."""
    return uncertainty_map(camera, information, sigma, grid, typical, prior).flatten(-2).nan_to_num(0.0).amax(-1)


@dataclass
class PoseSuggestion:
    """The candidate poses ranked by the uncertainty each would leave (:func:`next_poses`).

    Attributes:
        poses: :class:`CandidatePoses`, best first.
        worst_px: :math:`(K,)` the worst 1-sigma projection uncertainty over the image (px) after each.
        current_px: the worst now, before any of them.
        instruction: the best pose in words (:func:`pose_instruction`).
        score_px: :math:`(K,)` the fourth-power mean of the 1-sigma over the image's pixels in front of the camera
            (px) after each: what ranks them (:data:`RANK_POWER`).
    """

    poses: CandidatePoses
    worst_px: torch.Tensor
    current_px: float
    instruction: str
    score_px: torch.Tensor | None = None

    @property
    def tilt_deg(self) -> torch.Tensor:
        return self.poses.tilt_deg

    @property
    def gain(self) -> torch.Tensor:
        """:math:`(K,)` the relative drop of the figure each pose gives."""
        return 1.0 - self.worst_px / max(self.current_px, 1e-300)


def _side(x: float, low: str, high: str) -> str:
    return low if x < 0.4 else high if x > 0.6 else ""


def pose_instruction(position: torch.Tensor, fill: float, tilt_deg: torch.Tensor,
                     current_fill: float | None = None) -> str:
    """One line that tells a person holding the board where it goes: the image region, nearer or farther than now,
    and which edge turns away by about how much (rounded to 10 degrees).

    Args:
        position: ``(x, y)`` the board centre as fractions of the image.
        fill: the fraction of the image width the board spans there.
        tilt_deg: ``(about x, about y)`` degrees (positive: the bottom edge / the left edge away).
        current_fill: the board's fill now (``None``: say the fill itself).

    Example:
        >>> pose_instruction(torch.tensor([0.2, 0.2]), 0.7, torch.tensor([-30.0, 0.0]), current_fill=0.4)
        'top left, closer, top edge tilted about 30 degrees away'
        >>> pose_instruction(torch.tensor([0.5, 0.5]), 0.35, torch.tensor([0.0, 0.0]))
        'centre, filling about a third of the width, held flat'
    """
    x, y = float(position[0]), float(position[1])
    where = " ".join(w for w in (_side(y, "top", "bottom"), _side(x, "left", "right")) if w) or "centre"
    if current_fill is None:
        size = ("filling about a third of the width" if fill < 0.42 else "filling about half the width"
                if fill < 0.6 else "filling most of the width")
    else:
        ratio = fill / max(current_fill, 1e-9)
        size = "closer" if ratio > 1.15 else "farther" if ratio < 0.87 else "at this distance"
    turns = []
    for angle, pos, neg in ((float(tilt_deg[0]), "bottom", "top"), (float(tilt_deg[1]), "left", "right")):
        deg = int(round(abs(angle) / 10.0) * 10)
        if deg:
            turns.append(f"{pos if angle > 0 else neg} edge tilted about {deg} degrees away")
    return f"{where}, {size}, " + (" and ".join(turns) if turns else "held flat")


def next_poses(
    camera: Camera,
    information: torch.Tensor,
    object_points: torch.Tensor,
    sigma: float = 1.0,
    board_size: tuple[int, int] | None = None,
    candidates: CandidatePoses | None = None,
    current_fill: float | None = None,
    grid: tuple[int, int] = (16, 12),
    top: int | None = None,
    min_seen: float | None = None,
) -> PoseSuggestion:
    r"""Rank the poses a hand-held board reaches by the 1-sigma projection uncertainty over the image the calibration
    would have after a view there: its :data:`RANK_POWER`-th power mean over the grid's pixels whose rays point in
    front of the camera (the module docstring says why neither the worst nor the RMS, and why not behind).

    Args:
        camera: one camera with its image size (the current calibration's, or a guess before there is one).
        information: :math:`(P, P)` or :math:`(1, P, P)` the current information about the model's parameters
            (:func:`view_information` summed over the views taken; zeros before any), for corner weights 1.
        object_points: :math:`(N, 3)` the board's corners, grid order.
        sigma: the corners' standard deviation (px): the solver's residual RMS.
        board_size: ``(cols, rows)`` inner corners (the outline).
        candidates: the poses to rank (default: :func:`candidate_poses`).
        current_fill: the fraction of the image width the board spans now (the instruction's "closer"/"farther").
        grid: ``(across, down)`` pixels over which the mean and the worst are taken.
        top: keep only the best ``top``.
        min_seen: where ``candidates`` is not given, the fraction of the board the poses show at least (default
            :data:`MIN_SEEN`; 1 where the detector needs the whole board).

    Returns:
        :class:`PoseSuggestion`, best first (empty ``poses`` where no candidate fits the image).
    """
    info = information.double().to(camera.device)
    info = info[0] if info.dim() == 3 else info
    check_tensor(info, "information", ["P", "P"], P=camera.model.num_params)
    camera = camera.to(dtype=torch.float64)
    poses, M = _candidates_and_information(camera, object_points, board_size, candidates, min_seen)
    typical = M.mean(0) if len(poses) else info
    current = float(worst_uncertainty(camera, info, sigma, grid, typical))
    if len(poses):
        after = uncertainty_map(camera, info + M, sigma, grid, typical).flatten(-2).nan_to_num(0.0)
        seen = _pixel_jacobians(camera, grid)[3]
        worst, score = after.amax(-1), after[:, seen].pow(RANK_POWER).mean(-1).pow(1.0 / RANK_POWER)
    else:
        worst = score = M.new_zeros(0)
    order = torch.argsort(score)
    if top is not None:
        order = order[:top]
    ranked = poses.take(order)
    words = (pose_instruction(ranked.position[0], float(ranked.fill[0]), ranked.tilt_deg[0], current_fill)
             if len(ranked) else "")
    return PoseSuggestion(ranked, worst[order], current, words, score[order])


class NextBestPose(nn.Module):
    """:func:`next_poses` as a module: the candidate poses of one camera and board laid out once.

    Args:
        camera: one camera with its image size.
        object_points: :math:`(N, 3)`.
        board_size: ``(cols, rows)``.
        grid: ``(across, down)`` pixels.
        min_seen: the fraction of the board the poses show at least (default :data:`MIN_SEEN`).

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.models import PINHOLE
        >>> cam = Camera(PINHOLE, torch.tensor([600.0, 600, 320, 240], dtype=torch.float64), (640, 480))
        >>> nbp = NextBestPose(cam, board_object_points(9, 6, 0.03, dtype=torch.float64), (9, 6))
        >>> nbp(torch.zeros(4, 4, dtype=torch.float64), sigma=0.2).instruction != ""
        True
    """

    def __init__(self, camera: Camera, object_points: torch.Tensor, board_size: tuple[int, int] | None = None,
                 grid: tuple[int, int] = (16, 12), min_seen: float | None = None) -> None:
        super().__init__()
        self.camera = camera.to(dtype=torch.float64)
        self.object_points = object_points.double()
        self.board_size = board_size
        self.grid = grid
        self.candidates = candidate_poses(self.camera, self.object_points, board_size, min_seen=min_seen)

    def forward(self, information: torch.Tensor, sigma: float = 1.0, current_fill: float | None = None,
                top: int | None = None) -> PoseSuggestion:
        return next_poses(self.camera, information, self.object_points, sigma, self.board_size, self.candidates,
                          current_fill, self.grid, top)
