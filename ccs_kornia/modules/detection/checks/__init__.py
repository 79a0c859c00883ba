"""Checks of a found board: the whole-board checks (lattice, skipped lines, sides), the evidence of each corner and
the one policy deciding from it, partial boards (corners the image does not show), and which board size an image
shows (a wrong board size named early).

Names are imported lazily (PEP 562): importing this package loads none of its modules.
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "whole_board_check": "ccs_kornia.modules.detection.checks.board_checks",
    "CornerEvidence": "ccs_kornia.modules.detection.checks.corner_evidence",
    "decide_corners": "ccs_kornia.modules.detection.checks.corner_evidence",
    "board_grid_in": "ccs_kornia.modules.detection.checks.board_size",
    "board_size_in": "ccs_kornia.modules.detection.checks.board_size",
    "other_board_size": "ccs_kornia.modules.detection.checks.board_size",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
