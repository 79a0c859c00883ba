"""Whether a rig's board sag is worth keeping: the held-out epipolar RMS of the rig with and without it.

The rig's own held-out check (k folds of frames, :class:`~ccs_kornia.modules.rig.rig_solver.RigSolver`'s
``heldout_epipolar_rms``) measures what matters: how well the cameras and extrinsics fitted on some frames explain the
others. :func:`choose_rig_board_warp` keeps the sag (:mod:`~ccs_kornia.geometry.board_warp`, fitted with the rig by
``RigSolver(board_warp=True)``) where it lowers the median of the camera pairs' held-out figures by ``margin`` and the
views determine it (its larger coefficient ``min_sigmas`` standard deviations from 0): the single camera's rule
(:func:`~ccs_kornia.modules.calibration.board_flatness.keep_board_warp`).
"""

from __future__ import annotations

import math

import torch

from ccs_kornia.modules.calibration.board_flatness import (
    board_warp_record,
    keep_board_warp,
)
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


def choose_rig_board_warp(flat: RigResult, bent: RigResult, object_points: torch.Tensor, margin: float = 0.05,
                          min_sigmas: float = 3.0) -> tuple[RigResult, dict]:
    """The rig to use of a flat-board fit and a bent-board fit of the same frames (on the board ``object_points``
    :math:`(N, 3)`), and the figures (:func:`~ccs_kornia.modules.calibration.board_flatness.board_warp_record` with
    ``heldout_epipolar_px``) (module docstring)."""
    held_flat, held_bent = heldout_pairs(flat), heldout_pairs(bent)
    warp, std = bent.board_warp, bent.board_warp_std
    kept = bool(bent.success and flat.success and warp is not None and
                keep_board_warp(warp, std, object_points, held_flat, held_bent, margin, min_sigmas))
    return (bent if kept else flat), _record(kept, warp, std, held_flat, held_bent)


def not_determined(warp: torch.Tensor | None, std: torch.Tensor | None) -> dict:
    """The figures of a sag the frames do not determine (not kept, no held-out comparison made)."""
    return _record(False, warp, std, math.nan, math.nan)


def _record(kept, warp, std, held_flat, held_bent) -> dict:
    return board_warp_record(kept, warp, std, held_flat, held_bent, "heldout_epipolar_px")
