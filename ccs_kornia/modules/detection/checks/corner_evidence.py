"""What the image says about each corner of an organised board, and the one policy that decides from it.

After the grid organiser has placed a board and the missing cells are predicted, every corner carries the same
evidence (:class:`CornerEvidence`, ``(B, N)`` tensors measured once in torch): whether the network saw it or it was
predicted, whether the saddle refinement confirmed a saddle there, and its checker contrast relative to the board's.
:func:`decide_corners` turns that evidence into the corners the image does not show (left out, NaN) and the corners
that refuse their board (a predicted corner with neither a saddle nor a reason to be hidden).

The peaks' own evidence (heatmap sigma, X-junction circle) is judged before there is a grid, the point symmetry at full
resolution after (:func:`~ccs_kornia.modules.detection.checks.hidden_corners.settle_partial_boards`); ``docs/detection.md``
lists every check and its threshold.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ccs_kornia.modules.detection.checks.hidden_corners import (
    HIDDEN_CONTRAST_FRACTION,
    UNCONFIRMED_CONTRAST_FRACTION,
    glare_rim,
    relative_contrast,
    spans_board,
)

__all__ = ["CornerEvidence", "measure_corner_evidence", "decide_corners"]


@dataclass
class CornerEvidence:
    r"""Per-corner evidence of organised boards, :math:`(B, N)` in grid order unless noted.

    Attributes:
        cells: bool, the corners of the found boards.
        predicted: bool, cells without a peak of their own (predicted from their neighbours).
        saddle_ok: bool, the saddle refinement found a saddle there.
        contrast: float, checker contrast over the board's median on its confirmed corners
            (:func:`~ccs_kornia.modules.detection.checks.hidden_corners.relative_contrast`; NaN where it cannot be measured),
            or ``None`` where partial boards are not allowed (nothing is hidden then).
        spans_board: :math:`(B,)` bool, the peaks reach all four border lines of the board (one placement only).
    """

    cells: torch.Tensor
    predicted: torch.Tensor
    saddle_ok: torch.Tensor
    contrast: torch.Tensor | None
    spans_board: torch.Tensor

    @property
    def unconfirmed(self) -> torch.Tensor:
        """Predicted corners without a saddle, :math:`(B, N)` bool."""
        return self.predicted & ~self.saddle_ok


def measure_corner_evidence(
    images: torch.Tensor, corners: torch.Tensor, cells: torch.Tensor, predicted: torch.Tensor, saddle_ok: torch.Tensor,
    valid: torch.Tensor, board_size: tuple[int, int], contrast: bool = True,
) -> CornerEvidence:
    r"""Measure :class:`CornerEvidence` of refined boards.

    Args:
        images: :math:`(B, 1, H, W)` grey images in ``[0, 1]``.
        corners: :math:`(B, N, 2)` refined corners in grid order.
        cells: :math:`(B, N)` bool, the corners of found boards.
        predicted: :math:`(B, N)` bool, the cells the network missed.
        saddle_ok: :math:`(B, N)` bool, the refiner's verdict.
        valid: :math:`(B, N)` bool, the cells with a peak (the organiser's).
        board_size: ``(cols, rows)``.
        contrast: measure the checker contrast (only partial boards use it).

    Returns:
        :class:`CornerEvidence`.

    Example:
        >>> img = torch.zeros(1, 1, 96, 128)  # 4 x 3 squares of 32 px: 3 x 2 inner corners
        >>> for i in range(4):
        ...     for j in range(3):
        ...         img[..., 32 * j:32 * j + 32, 32 * i:32 * i + 32] = float((i + j) % 2)
        >>> img[..., :, 80:] = 1.0  # glare over the right-hand squares
        >>> pts = torch.tensor([[[32.0 * i - 0.5, 32.0 * j - 0.5] for j in (1, 2) for i in (1, 2, 3)]])
        >>> seen = torch.tensor([[True, True, False, True, True, False]])
        >>> ev = measure_corner_evidence(img, pts, torch.ones(1, 6, dtype=torch.bool), ~seen, seen, seen, (3, 2))
        >>> ev.contrast.tolist(), ev.spans_board.tolist()
        ([[1.0, 1.0, 0.0, 1.0, 1.0, 0.0]], [False])
    """
    unconfirmed = predicted & ~saddle_ok
    rel = relative_contrast(images, corners, cells & ~unconfirmed, board_size) if contrast else None
    return CornerEvidence(cells, predicted, saddle_ok, rel, spans_board(valid, board_size))


def decide_corners(evidence: CornerEvidence, board_size: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    r"""The policy: which corners the image does not show, and which refuse their board.

    * hidden: the checker has all but faded (contrast below :data:`HIDDEN_CONTRAST_FRACTION` of the board's: glare,
      an occluder, a corner outside the image; confirmed saddles there are off by pixels), or a predicted corner has no
      saddle and the checker has faded (below :data:`UNCONFIRMED_CONTRAST_FRACTION`: at a glare's rim the saddles are
      lost first);
    * at a glare's rim (next to a hidden corner) nothing is taken on trust: a faded corner is hidden even with a
      saddle (the glare's edge pulls it by pixels), and so is an unconfirmed one (the saddle lost while most of the
      contrast shows) where the board's peaks span the board (a shorter lattice was placed by the image, and its
      unconfirmed corners are what refuses a wrong placement); the cases behind these rules: ``docs/measurements.md``;
    * refusing: a predicted corner without a saddle that is not hidden (one wrong corner ruins a calibration).

    Without contrast (no partial boards) nothing is hidden.

    Args:
        evidence: :class:`CornerEvidence`.
        board_size: ``(cols, rows)``.

    Returns:
        ``hidden`` :math:`(B, N)` bool and ``refusing`` :math:`(B, N)` bool.

    Example:
        >>> seen = torch.tensor([[True, True, False, True, True, False]])
        >>> ev = CornerEvidence(torch.ones(1, 6, dtype=torch.bool), ~seen, seen,
        ...                     torch.tensor([[1.0, 1.0, 0.0, 1.0, 1.0, 0.9]]), torch.tensor([False]))
        >>> hidden, refusing = decide_corners(ev, (3, 2))
        >>> hidden.tolist(), refusing.any().item()
        ([[False, False, True, False, False, False]], True)
    """
    unconfirmed = evidence.unconfirmed
    hidden = torch.zeros_like(unconfirmed)
    if evidence.contrast is not None:
        rel, cells = evidence.contrast, evidence.cells
        faded = (rel < UNCONFIRMED_CONTRAST_FRACTION).nan_to_num(False)
        hidden = cells & ((rel < HIDDEN_CONTRAST_FRACTION).nan_to_num(False) | (unconfirmed & faded))
        rim = glare_rim(cells, hidden, board_size)
        hidden |= rim & ((unconfirmed & evidence.spans_board[:, None]) | faded)
    return hidden, unconfirmed & ~hidden
