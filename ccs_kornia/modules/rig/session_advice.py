"""What a rig's session should record differently: the advice drawn from a solved rig's frames.

A hand-held session (webcams, a board waved in front of them, frames paired by a software sync) fails in known ways;
each is measured on the solved rig and turned into one line of advice:

* **weakly linked cameras**: a pair whose frames both cameras use carry few effective frames (the frames' robust
  weights summed, :func:`shared_frames`) below :data:`WEAK_LINK_FRAMES`;
* **boards too small**: a camera whose boards cover a median below :data:`SMALL_BOARD` of its image;
* **image corners left out**: a camera whose boards together cover less than :data:`OUTER_RING` of the outer ring of
  its image (:func:`~ccs_kornia.modules.calibration.quality.coverage.image_coverage`), where the distortion is largest;
* **a board moving between exposures**: more than :data:`DISAGREEING_SHARE` of the frames two cameras see weighed
  below one half for their disagreement (:mod:`~ccs_kornia.modules.rig.frame_consistency`);
* **intrinsics the rig moved**: a camera whose joint-fit intrinsics left its own calibration by more than
  :data:`MOVED_SIGMA` of its single-camera 1-sigma (the solver passes the moves of the cameras its frames dragged).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.modules.calibration.quality.coverage import image_coverage
from ccs_kornia.modules.rig.frame_consistency import BOARD_MOVING, disagreement_cause
from ccs_kornia.modules.rig.rig_state import RigState

__all__ = ["DISAGREEING_SHARE", "MOVED_SIGMA", "OUTER_RING", "SMALL_BOARD", "WEAK_LINK_FRAMES", "board_fraction",
           "session_advice", "shared_frames"]

#: a pair of cameras whose shared frames weigh less than this together is weakly linked
WEAK_LINK_FRAMES = 5.0
#: a camera whose boards cover a median below this fraction of its image is told to bring the board closer
SMALL_BOARD = 0.10
#: a camera whose boards cover less than this fraction of its image's outer ring is told to show the board there
OUTER_RING = 0.25
#: more than this fraction of the shared frames weighing below one half: the board moved between exposures
DISAGREEING_SHARE = 0.2
#: intrinsics moved by more than this many single-camera sigmas are reported
MOVED_SIGMA = 3.0


def shared_frames(used: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Effective shared frames :math:`(C, C)` of every pair: the weights of the frames both cameras use, summed (the
    diagonal: each camera's own).

    Args:
        used: :math:`(C, F)` bool observations; weight: :math:`(F,)` frame weights (NaN counts as 0).

    Example:
        >>> used = torch.tensor([[True, True, False], [True, True, True]])
        >>> shared_frames(used, torch.tensor([1.0, 0.5, 1.0])).tolist()
        [[1.5, 1.5], [1.5, 2.5]]
    """
    u = used.to(weight.dtype) * weight.nan_to_num(0.0)[None]
    return u @ used.to(weight.dtype).T


def board_fraction(model: CameraModel, params: torch.Tensor, Rc: torch.Tensor, tc: torch.Tensor,
                   object_points: torch.Tensor, image_size: tuple[int, int]) -> torch.Tensor:
    r"""Fraction of the image the board's outline covers in each view (the whole board, seen or not; clipped to 1).

    Args:
        model: the camera's model; params: :math:`(P,)`.
        Rc, tc: :math:`(F, 3, 3)`, :math:`(F, 3)` board -> camera.
        object_points: :math:`(N, 3)` planar board points (their bounding rectangle is the outline).
        image_size: ``(W, H)``.

    Returns:
        :math:`(F,)`.

    Example:
        >>> from ccs_kornia.geometry.models import PINHOLE
        >>> obj = torch.tensor([[0.0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0.1, 0.1, 0]], dtype=torch.float64)
        >>> p = torch.tensor([100.0, 100.0, 50.0, 50.0], dtype=torch.float64)
        >>> R, t = torch.eye(3, dtype=torch.float64)[None], torch.tensor([[-0.05, -0.05, 0.2]], dtype=torch.float64)
        >>> board_fraction(PINHOLE, p, R, t, obj, (100, 100)).tolist()
        [0.25]
    """
    lo, hi = object_points[:, :2].amin(0), object_points[:, :2].amax(0)
    z = object_points[:, 2].mean()
    outline = torch.stack([torch.stack([lo[0], lo[1], z]), torch.stack([hi[0], lo[1], z]),
                           torch.stack([hi[0], hi[1], z]), torch.stack([lo[0], hi[1], z])]).to(tc)
    X = (Rc @ outline.T).transpose(-1, -2) + tc[:, None]  # (F, 4, 3)
    uv = model.columns(X[None], params[None].to(tc), jacobians=False)[0][0]
    x, y = uv[..., 0], uv[..., 1]
    area = 0.5 * (x * y.roll(-1, -1) - x.roll(-1, -1) * y).sum(-1).abs()
    return (area / float(image_size[0] * image_size[1])).clamp(max=1.0)


def _pct(x: float) -> str:
    return f"{100 * x:.0f} %"


def session_advice(
    names: Sequence[str],
    image_sizes: Sequence[tuple[int, int]],
    rig: RigState,
    object_points: torch.Tensor,
    corners: torch.Tensor,
    valid: torch.Tensor,
    used: torch.Tensor,
    disagreement: torch.Tensor,
    weight: torch.Tensor,
    motion: torch.Tensor,
    shared: torch.Tensor,
    moved_sigma: Sequence[torch.Tensor],
    fixed: Sequence[bool],
) -> list[str]:
    """What to record next, one line per finding (see the module doc), the most useful first.

    Args:
        names, image_sizes: per camera.
        rig: the solved rig (:class:`~ccs_kornia.modules.rig.rig_state.RigState` of one rig, ``B = 1``).
        object_points: :math:`(N, 3)`; corners: :math:`(C, F, N, 2)`; valid: :math:`(C, F, N)`; used: :math:`(C, F)`.
        disagreement, weight, motion: :math:`(F,)` per frame (:mod:`~ccs_kornia.modules.rig.frame_consistency`).
        shared: :math:`(C, C)` effective shared frames (:func:`shared_frames`).
        moved_sigma: per camera :math:`(P_c,)` the intrinsics' move in single-camera sigmas; fixed: per camera.

    Returns:
        Lines of advice (empty when the session needs nothing more).
    """
    C = len(names)
    lines: list[str] = []
    Rc, tc = rig.board_poses()
    obj = object_points.to(tc)
    weak = [(names[i], names[j], float(shared[i, j])) for i in range(C) for j in range(i + 1, C)
            if 0 < float(shared[i, j]) < WEAK_LINK_FRAMES]
    if weak:
        lines.append(f"show the board to {'; '.join(f'{a} and {b}' for a, b, _ in weak)} together: "
                     f"{'their links rest' if len(weak) > 1 else 'their link rests'} on "
                     f"{', '.join(f'{s:.1f}' for _, _, s in weak)} frames that one board pose explains")
    shared_any = used.sum(0) >= 2
    w = weight.nan_to_num(1.0)
    low = shared_any & (w < 0.5)
    n_shared, n_low = int(shared_any.sum()), int(low.sum())
    if n_shared and n_low > DISAGREEING_SHARE * n_shared:
        d = float(disagreement[low].median())
        causes = [disagreement_cause(float(disagreement[f]), float(motion[f])) for f in torch.nonzero(low).flatten()]
        moving = causes.count(BOARD_MOVING) >= max(1, len(causes) // 2)
        unknown = all(not c for c in causes)
        what = ("move the board slowly, or hold it still at each pose" if moving or unknown else
                "check the cameras' synchronisation and how their frames were paired")
        lines.append(f"{what}: {n_low} of the {n_shared} frames two cameras see disagree between the cameras (median "
                     f"{d:.1f} px)" + (", the board moving between their exposures" if moving else ""))
    small, ring, moved = [], [], []
    for c in range(C):
        views = used[c]
        if not bool(views.any()):
            continue
        frac = board_fraction(rig.models[c], rig.params[c][0], Rc[0, c][views], tc[0, c][views], obj, image_sizes[c])
        median = float(frac.median())
        if median < SMALL_BOARD:
            small.append((names[c], median))
        cov = image_coverage(corners[c][None].nan_to_num(0.0), valid[c][None], obj, views[None], image_sizes[c])[0]
        if float(cov[1]) < OUTER_RING:
            ring.append((names[c], float(cov[1])))
        m = float(moved_sigma[c].abs().max()) if moved_sigma[c].numel() and not fixed[c] else 0.0
        if m > MOVED_SIGMA:
            moved.append((names[c], m))
    if small:
        lines.append(f"bring the board closer to {_names(small)} (or use a larger board): it covers a median "
                     f"{', '.join(_pct(v) for _, v in small)} of {'its image' if len(small) == 1 else 'their images'}")
    if ring:
        lines.append(f"show the board nearer the corners and edges of the image of {_names(ring)}: the boards cover "
                     f"{', '.join(_pct(v) for _, v in ring)} of {'its' if len(ring) == 1 else 'their'} outer ring"
                     f"{'' if len(ring) == 1 else 's'}")
    if moved:
        lines.append(f"record views of {_names(moved)} alone, spread over the image: the joint fit moved "
                     f"{'its' if len(moved) == 1 else 'their'} intrinsics up to "
                     f"{', '.join(f'{v:.1f}' for _, v in moved)} sigma from "
                     f"{'its own calibration' if len(moved) == 1 else 'their own calibrations'}")
    return lines


def _names(items: list[tuple[str, float]]) -> str:
    names = [n for n, _ in items]
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]
