r"""Whether the board's sag is worth keeping: the held-out error of split halves with and without it.

Estimating two more unknowns always lowers the residuals of the views they were fitted on; what matters is whether the
camera predicts views it has not seen better. :func:`choose_board_warp` splits a camera's used views into two halves
(alternate views, so both halves span the session), calibrates each half with a flat board and with the sag, and
projects the other half's corners with each half's camera (the other half's poses refitted with the camera held, on
the board as that half found it). The sag is kept where its median held-out error is lower by ``margin`` and the sag
itself is determined (its larger coefficient at least ``min_sigmas`` standard deviations from 0); the camera then is
the whole set's calibration with the sag (:class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver` with
``board_warp``), its coefficients and 1-sigma in the result.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, replace

import torch

from ccs_kornia.geometry.board_warp import warped_board
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.modules.calibration.corrected_frame import select_cameras
from ccs_kornia.modules.calibration.lm import levenberg_marquardt
from ccs_kornia.modules.calibration.result import CalibrationResult
from ccs_kornia.modules.calibration.solver import CalibrationSolver

__all__ = ["BoardWarpChoice", "board_warp_determined", "board_warp_record", "choose_board_warp", "heldout_errors",
           "keep_board_warp", "split_halves"]

#: a sag below this fraction of the board's extent is no bend at all (0.2 um on a 0.2 m board): noise-free views
#: "determine" a zero sag to many standard deviations of nothing
MIN_SAG = 1e-6


def board_warp_determined(warp: torch.Tensor | None, std: torch.Tensor | None, object_points: torch.Tensor,
                          min_sigmas: float = 3.0) -> torch.Tensor | bool:
    """Whether the views determine a sag: its larger coefficient ``min_sigmas`` standard deviations from 0 and above
    :data:`MIN_SAG` of the board's extent (``(..., 2)`` coefficients give ``(...)``; ``False`` without a sag).

    Example:
        >>> obj = torch.tensor([[0.0, 0, 0], [0.2, 0.1, 0]])
        >>> board_warp_determined(torch.tensor([-1e-3, 1e-5]), torch.tensor([1e-5, 1e-5]), obj).item()
        True
    """
    if warp is None or std is None:
        return False
    extent = float((object_points[..., :2].amax(-2) - object_points[..., :2].amin(-2)).amax())
    ratio = (warp.abs() / std).nan_to_num(0.0, posinf=0.0)
    return (ratio.amax(-1) >= min_sigmas) & (warp.abs().amax(-1) > MIN_SAG * extent)


def keep_board_warp(warp: torch.Tensor | None, std: torch.Tensor | None, object_points: torch.Tensor,
                    heldout_flat: torch.Tensor, heldout_warp: torch.Tensor, margin: float = 0.05,
                    min_sigmas: float = 3.0) -> torch.Tensor | bool:
    """The rule of every fit that observes a board: keep the sag where the views determine it
    (:func:`board_warp_determined`) and its held-out error is below ``(1 - margin)`` times the flat board's (the
    fit's own held-out figure: split halves for a camera, the rig's k folds, a robot's left-out poses).

    Example:
        >>> obj = torch.tensor([[0.0, 0, 0], [0.2, 0.1, 0]])
        >>> w, s = torch.tensor([-1e-3, 1e-5]), torch.tensor([1e-5, 1e-5])
        >>> [bool(keep_board_warp(w, s, obj, torch.tensor(0.9), torch.tensor(h))) for h in (0.6, 0.88)]
        [True, False]
    """
    held_flat = torch.as_tensor(heldout_flat, dtype=torch.float64)
    held_warp = torch.as_tensor(heldout_warp, dtype=torch.float64)
    return board_warp_determined(warp, std, object_points, min_sigmas) & (held_warp < (1 - margin) * held_flat)


def board_warp_record(kept: bool, warp: torch.Tensor | None, std: torch.Tensor | None, heldout_flat: float,
                      heldout_warp: float, heldout: str = "heldout_median_px") -> dict:
    """One fit's sag as JSON (the ``board_flatness`` block of every command that fits a board): ``kept``, the
    coefficients ``warp_m`` and 1-sigma ``std_m`` (:math:`(2,)`, ``None`` where not finite), the held-out figure
    with a flat and a bent board under the name ``heldout`` and the model.

    Example:
        >>> r = board_warp_record(True, torch.tensor([-1e-3, 5e-4]), torch.tensor([1e-5, 1e-5]), 0.9, 0.6)
        >>> r["kept"], r["heldout_median_px"]
        (True, {'flat': 0.9, 'warp': 0.6})
    """

    def num(x) -> float | None:
        x = float(x)
        return x if math.isfinite(x) else None

    return {
        "kept": bool(kept),
        "warp_m": None if warp is None else [num(v) for v in warp],
        "std_m": None if std is None else [num(v) for v in std],
        heldout: {"flat": num(heldout_flat), "warp": num(heldout_warp)},
        "model": "mrcal's calobject_warp: dz = c_x (1 - u^2) + c_y (1 - v^2), u, v in [-1, 1] over the board",
    }


@dataclass
class BoardWarpChoice:
    """What :func:`choose_board_warp` found for C cameras.

    Attributes:
        result: the calibration to use: the sag's where it is kept, the flat board's elsewhere (``board_warp`` 0 and
            ``std_board_warp`` NaN there).
        kept: :math:`(C,)` bool, the sag is kept.
        warp: :math:`(C, 2)` the sag fitted on all the views (mrcal's ``calobject_warp``, board units; NaN where it
            could not be solved), whether kept or not.
        std: :math:`(C, 2)` its 1-sigma.
        heldout_flat: :math:`(C,)` median held-out error (px) of the halves with a flat board.
        heldout_warp: :math:`(C,)` the same with the sag.
    """

    result: CalibrationResult
    kept: torch.Tensor
    warp: torch.Tensor
    std: torch.Tensor
    heldout_flat: torch.Tensor
    heldout_warp: torch.Tensor

    def record(self, camera: int) -> dict:
        """One camera's figures as JSON (the calibration record's ``board_flatness``, :func:`board_warp_record`)."""
        return board_warp_record(bool(self.kept[camera]), self.warp[camera], self.std[camera],
                                 self.heldout_flat[camera], self.heldout_warp[camera])


def split_halves(used: torch.Tensor) -> torch.Tensor:
    """:math:`(2, C, V)` bool: each camera's used views in two halves, alternately in the views' order.

    Example:
        >>> split_halves(torch.tensor([[True, False, True, True, True]])).long().tolist()
        [[[1, 0, 0, 1, 0]], [[0, 0, 1, 0, 1]]]
    """
    rank = used.long().cumsum(-1) - 1
    even = used & (rank % 2 == 0)
    return torch.stack([even, used & ~even])


def heldout_errors(camera_of: CalibrationResult, corners: torch.Tensor, valid: torch.Tensor, views: torch.Tensor,
                   object_points: torch.Tensor, start: CalibrationResult, weights: torch.Tensor | None = None,
                   dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """Per-corner errors :math:`(C, V, N)` (px, NaN elsewhere) of ``views`` under ``camera_of``'s camera and board
    (its sag where it has one), each view's pose refitted with the camera held (from ``start``'s poses)."""
    obj = object_points.to(corners.device, dtype)
    if camera_of.board_warp is not None:
        obj = warped_board(obj, camera_of.board_warp.to(obj).nan_to_num(0.0))
    model = camera_of.camera.model
    params = camera_of.camera.params.to(dtype).nan_to_num(1.0)
    w = (valid & views[..., None]).to(dtype)
    w = w if weights is None else w * weights.to(dtype)
    fit = levenberg_marquardt(model, params, start.rvec.to(dtype), start.tvec.to(dtype), obj, corners.to(dtype), w,
                              free=[False] * model.num_params, dtype=dtype)
    C, V, N = corners.shape[:3]
    o = obj if obj.dim() == 3 else obj.expand(C, N, 3)
    uv = Camera(model, params, camera_of.camera.image_size).project(o[:, None].expand(C, V, N, 3), fit.rvec, fit.tvec)
    err = (uv - corners.to(dtype)).norm(dim=-1)
    keep = valid & views[..., None] & (camera_of.success.to(valid.device)[:, None, None])
    return torch.where(keep, err, torch.full_like(err, float("nan")))


def _median(errors: list[torch.Tensor]) -> torch.Tensor:
    e = torch.cat([x.flatten(1) for x in errors], -1)
    return e.nanmedian(-1).values


def choose_board_warp(solver: CalibrationSolver, usual: CalibrationResult, corners: torch.Tensor, valid: torch.Tensor,
                      object_points: torch.Tensor, image_size: tuple[int, int], weights: torch.Tensor | None = None,
                      margin: float = 0.05, min_sigmas: float = 3.0) -> BoardWarpChoice:
    r"""The board's sag fitted beside a flat-board calibration ``usual``, kept where held-out views say it helps
    (module docstring).

    Args:
        solver: the flat-board :class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver` that made ``usual``
            (an OpenCV or the fisheye model; its options are used for every solve, with ``board_warp`` for the sag's).
        usual: its result for C cameras (batched).
        corners: :math:`(C, V, N, 2)`; valid: :math:`(C, V, N)`; object_points: :math:`(N, 3)`; image_size ``(W, H)``;
        weights: :math:`(C, V, N)` or ``None``: as ``usual`` was solved.
        margin: the sag's median held-out error must be below ``(1 - margin)`` times the flat board's.
        min_sigmas: the sag's larger coefficient must be this many standard deviations from 0.

    Returns:
        :class:`BoardWarpChoice`.

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.camera import project_points
        >>> obj = board_object_points(7, 6, 0.05, dtype=torch.float64)
        >>> g = torch.Generator().manual_seed(0)
        >>> rvec = 0.8 * (torch.rand(12, 3, generator=g, dtype=torch.float64) - 0.5)
        >>> tvec = torch.tensor([-0.15, -0.12, 0.6], dtype=torch.float64).expand(12, 3)
        >>> K = torch.tensor([[600.0, 0, 320], [0, 600, 240], [0, 0, 1]], dtype=torch.float64)
        >>> bent = warped_board(obj, torch.tensor([-0.002, 0.001], dtype=torch.float64))
        >>> uv = project_points(bent.expand(12, -1, -1), K.expand(12, 3, 3), None, rvec, tvec)[None]
        >>> from ccs_kornia.geometry.models import K1K2
        >>> solver = CalibrationSolver(model=K1K2)
        >>> usual = solver(uv, None, obj, (640, 480))
        >>> choice = choose_board_warp(solver, usual, uv, uv.isfinite().all(-1), obj, (640, 480))
        >>> bool(choice.kept[0]), [round(w * 1000, 3) for w in choice.warp[0].tolist()]
        (True, [-2.0, 1.0])
    """
    bent = copy.copy(solver)
    bent.board_warp = True
    flat = copy.copy(solver)
    flat.board_warp = False
    C = corners.shape[0]
    device = corners.device
    valid = valid.to(device).bool() & corners.isfinite().all(-1)
    with torch.inference_mode():
        whole = bent(corners, valid, object_points, image_size, initial=usual, weights=weights)
        warp, std = whole.board_warp, whole.std_board_warp
        ok = whole.success & usual.success
        determined = board_warp_determined(warp, std, object_points, min_sigmas) & ok
        heldout_flat = heldout_warp = torch.full((C,), float("nan"), dtype=warp.dtype, device=warp.device)
        if bool(determined.any()):  # (a sag the views do not determine is not kept: no halves to solve)
            halves = split_halves(usual.used.to(device) & determined.to(device)[:, None])
            errors = {"flat": [], "warp": []}
            for h in range(2):
                part = valid & halves[h][..., None]
                other = halves[1 - h]
                for name, s in (("flat", flat), ("warp", bent)):
                    half = s(corners, part, object_points, image_size, initial=usual, weights=weights)
                    errors[name].append(heldout_errors(half, corners, valid, other, object_points, usual, weights))
            heldout_flat, heldout_warp = _median(errors["flat"]), _median(errors["warp"])
    kept = ok & keep_board_warp(warp, std, object_points, heldout_flat, heldout_warp, margin, min_sigmas)
    flat_like = replace(usual, board_warp=torch.zeros(C, 2, dtype=warp.dtype, device=warp.device),
                        std_board_warp=torch.full((C, 2), float("nan"), dtype=warp.dtype, device=warp.device))
    return BoardWarpChoice(select_cameras(kept, whole, flat_like), kept, warp, std, heldout_flat, heldout_warp)
