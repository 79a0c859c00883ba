r"""One policy for a marker board's two paths: the marker path's corners and the lattice path's, merged per corner id.

* a corner both paths give, at the same place (within :data:`AGREE_PX`), is kept (the first path's);
* a corner both give at different places is dropped: one of the two ids is wrong, and which cannot be told;
* a corner only one path gives is kept;
* two corner ids at one place (closer than :data:`COLLISION` times the view's median distance between neighbouring
  corners) are both dropped;
* a corner id that one path found disputed (a marker beside it reads as another marker) is dropped from both.

A wrong id is worse than a missing corner, so every disagreement loses the corner.

A found view's reason ends with how many corners each path named before the merge (:func:`paths_note`), which
``detect`` and ``calibrate`` write per view as ``corners_by_path`` (:func:`corners_by_path`).
"""

from __future__ import annotations

import re
from enum import Enum

import torch

from ccs_kornia.runtime.checks import check_points, check_same_shape

__all__ = ["AGREE_PX", "COLLISION", "MarkerPaths", "corners_by_path", "merge_corners", "path_counts", "paths_note"]

#: two paths agree on a corner within this distance (px); both refine it with the same saddle fit
AGREE_PX = 1.0
#: two ids closer than this fraction of the view's median neighbour distance are one corner
COLLISION = 0.3


class MarkerPaths(Enum):
    """Which paths find a marker board's corners: ``MARKERS`` (each corner from the markers OpenCV decodes beside it),
    ``LATTICE`` (the heatmap network's lattice named by the markers that can be read) or ``BOTH`` (merged by
    :func:`merge_corners`)."""

    MARKERS = "markers"
    LATTICE = "lattice"
    BOTH = "both"

    @property
    def markers(self) -> bool:
        """The marker path runs."""
        return self is not MarkerPaths.LATTICE

    @property
    def lattice(self) -> bool:
        """The lattice path runs."""
        return self is not MarkerPaths.MARKERS


def merge_corners(first: torch.Tensor, second: torch.Tensor, veto: torch.Tensor | None = None
                  ) -> tuple[torch.Tensor, torch.Tensor]:
    r"""The corners of two paths :math:`(B, N, 2)` (NaN where a path has none) merged per id (module docstring):
    the merged corners :math:`(B, N, 2)` and the ids dropped as disputed :math:`(B, N)`. ``veto`` :math:`(B, N)`:
    ids a path found disputed (a marker there reads as another one), dropped from both.

    Example:
        >>> nan = float("nan")
        >>> a = torch.tensor([[[10.0, 10.0], [30.0, 10.0], [nan, nan], [50.0, 50.0]]])
        >>> b = torch.tensor([[[10.2, 10.0], [40.0, 10.0], [10.0, 30.0], [nan, nan]]])
        >>> merged, disputed = merge_corners(a, b)
        >>> merged[0].tolist(), disputed[0].tolist()
        ([[10.0, 10.0], [nan, nan], [10.0, 30.0], [50.0, 50.0]], [False, True, False, False])
    """
    check_points(first, "first")
    check_same_shape(second, "second", first, "first")
    has1, has2 = first.isfinite().all(-1), second.isfinite().all(-1)
    both = has1 & has2
    apart = (first - second).norm(dim=-1) > AGREE_PX
    disputed = both & apart
    if veto is not None:
        disputed = disputed | (veto.to(disputed.device).bool() & (has1 | has2))
    merged = torch.where(has1[..., None], first, second)
    keep = (has1 | has2) & ~disputed
    # two ids at one place: both dropped
    for k in range(merged.shape[0]):
        idx = keep[k].nonzero().flatten()
        if idx.numel() < 3:
            continue
        p = merged[k, idx]
        d = torch.cdist(p.double(), p.double())
        d.fill_diagonal_(float("inf"))
        nearest = d.min(1).values
        clash = (d < COLLISION * nearest.median()).any(1)
        disputed[k, idx[clash]] = True
        keep[k, idx[clash]] = False
    merged = torch.where(keep[..., None], merged, torch.full_like(merged, float("nan")))
    return merged, disputed


_NOTE = re.compile(r"\(named by the marker path: (\d+), the lattice path: (\d+)\)")


def path_counts(first: torch.Tensor, second: torch.Tensor) -> list[tuple[int, int]]:
    r"""Per view, the corners each path named :math:`(B, N, 2)` (NaN where none; the marker path's, the lattice
    path's), before they are merged.

    Example:
        >>> nan = float("nan")
        >>> path_counts(torch.tensor([[[1.0, 1.0], [nan, nan]]]), torch.tensor([[[1.0, 1.0], [2.0, 2.0]]]))
        [(1, 2)]
    """
    a = first.isfinite().all(-1).sum(-1).tolist()
    b = second.isfinite().all(-1).sum(-1).tolist()
    return list(zip(a, b))


def paths_note(marker: int, lattice: int) -> str:
    """The end of a found view's reason: how many corners each path named (:func:`corners_by_path` reads it back).

    Example:
        >>> paths_note(20, 24)
        ' (named by the marker path: 20, the lattice path: 24)'
    """
    return f" (named by the marker path: {int(marker)}, the lattice path: {int(lattice)})"


def corners_by_path(reason: str | None) -> dict[str, int] | None:
    """``{"marker_path": m, "lattice_path": l}`` from a reason ending in :func:`paths_note` (``None`` otherwise: a
    chessboard, or a view neither path found).

    Example:
        >>> corners_by_path("charuco: 17 DICT_6X6_250 markers, 24 of 24 corners" + paths_note(20, 24))
        {'marker_path': 20, 'lattice_path': 24}
        >>> corners_by_path("sb") is None
        True
    """
    m = _NOTE.search(reason or "")
    return None if m is None else {"marker_path": int(m.group(1)), "lattice_path": int(m.group(2))}
