"""Whether a rig's board sag is worth keeping: the held-out epipolar RMS of the rig with and without it.

The rig's own held-out check (k folds of frames, :class:`~ccs_kornia.modules.rig.rig_solver.RigSolver`'s
``heldout_epipolar_rms``) measures what matters: how well the cameras and extrinsics fitted on some frames explain the
others. :func:`choose_rig_board_warp` keeps the sag (:mod:`~ccs_kornia.geometry.board_warp`, fitted with the rig by
``RigSolver(board_warp=True)``) where it lowers the median of the camera pairs' held-out figures by ``margin`` and the
views determine it (its larger coefficient ``min_sigmas`` standard deviations from 0), as the single camera's rule does
(:mod:`~ccs_kornia.modules.calibration.board_flatness`).
"""

from __future__ import annotations

import math

import torch

from ccs_kornia.modules.rig.rig_solver import RigResult

__all__ = ["choose_rig_board_warp", "heldout_pairs", "not_determined"]


def heldout_pairs(rig: RigResult) -> float:
    """The median held-out epipolar RMS (px) over the rig's camera pairs (NaN where not measured).

    Example:
        >>> from types import SimpleNamespace
        >>> h = torch.tensor([[0.0, 0.25, 0.5], [0.25, 0.0, float("nan")], [0.5, float("nan"), 0.0]])
        >>> heldout_pairs(SimpleNamespace(heldout_epipolar_rms=h))
        0.25
    """
    h = rig.heldout_epipolar_rms
    C = h.shape[0]
    upper = h[torch.triu(torch.ones(C, C, dtype=torch.bool, device=h.device), 1)]
    upper = upper[upper.isfinite()]
    return float(upper.median()) if upper.numel() else math.nan


def choose_rig_board_warp(flat: RigResult, bent: RigResult, margin: float = 0.05,
                          min_sigmas: float = 3.0) -> tuple[RigResult, dict]:
    """The rig to use of a flat-board fit and a bent-board fit of the same frames, and the figures
    (``{"kept", "warp_m", "std_m", "heldout_epipolar_px": {"flat", "warp"}}``) (module docstring)."""
    held_flat, held_bent = heldout_pairs(flat), heldout_pairs(bent)
    warp, std = bent.board_warp, bent.board_warp_std
    determined = bent.success and warp is not None and bool((warp.abs() / std).amax() >= min_sigmas)
    kept = bool(determined and flat.success and held_bent < (1 - margin) * held_flat)
    return (bent if kept else flat), _record(kept, warp, std, held_flat, held_bent)


def not_determined(warp: torch.Tensor | None, std: torch.Tensor | None) -> dict:
    """The figures of a sag the frames do not determine (not kept, no held-out comparison made)."""
    return _record(False, warp, std, math.nan, math.nan)


def _num(x: float) -> float | None:
    return x if math.isfinite(x) else None


def _record(kept, warp, std, held_flat, held_bent) -> dict:
    return {
        "kept": kept,
        "warp_m": [_num(float(v)) for v in warp] if warp is not None else None,
        "std_m": [_num(float(v)) for v in std] if std is not None else None,
        "heldout_epipolar_px": {"flat": _num(held_flat), "warp": _num(held_bent)},
        "model": "mrcal's calobject_warp: dz = c_x (1 - u^2) + c_y (1 - v^2), u, v in [-1, 1] over the board",
    }
