"""Corner peaks to a board in grid order: the organiser and its lattice, the evidence the image gives the lattice, the
cells the detector missed, the paper's collinearity refinement and the grid's geometry (spacing, bend).

Names are imported lazily (PEP 562): importing this package loads none of its modules.
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "organize_grid": "ccs_kornia.modules.detection.grid.grid_organizer",
    "GridOrganizer": "ccs_kornia.modules.detection.grid.grid_organizer",
    "CollinearityRefiner": "ccs_kornia.modules.detection.grid.collinearity",
    "predict_missing_corners": "ccs_kornia.modules.detection.grid.missing_corners",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
