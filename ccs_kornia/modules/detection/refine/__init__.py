"""Sub-pixel corners on the image itself: the saddle fit and the point-symmetry polish, full-resolution refinement
of boards found on a level, per-corner precision and the differentiable corners.

Names are imported lazily (PEP 562): importing this package loads none of its modules.
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "CornerRefiner": "ccs_kornia.modules.detection.refine.saddle_refine",
    "refine_corners": "ccs_kornia.modules.detection.refine.saddle_refine",
    "symmetry_polish": "ccs_kornia.modules.detection.refine.symmetry_refine",
    "corner_uncertainty": "ccs_kornia.modules.detection.refine.corner_uncertainty",
    "corner_weights": "ccs_kornia.modules.detection.refine.corner_uncertainty",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
