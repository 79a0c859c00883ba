"""Detection on a warped copy of the images, corners mapped back exactly: the one warp -> detect -> map back -> refine
routine (:mod:`.warped_detection`) and the looks' warps: the copy straightened by the pooled correction
(:mod:`.corrected_copy`) and virtual pinhole views of a calibrated lens (:mod:`.virtual_view`).

Names are imported lazily (PEP 562): importing this package loads none of its modules.
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "Warp": "ccs_kornia.modules.detection.warps.warped_detection",
    "Downscale": "ccs_kornia.modules.detection.warps.warped_detection",
    "detect_warped": "ccs_kornia.modules.detection.warps.warped_detection",
    "map_back": "ccs_kornia.modules.detection.warps.warped_detection",
    "CorrectedCopy": "ccs_kornia.modules.detection.warps.corrected_copy",
    "VirtualView": "ccs_kornia.modules.detection.warps.virtual_view",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
