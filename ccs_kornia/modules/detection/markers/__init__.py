"""Marker boards: ChArUco and Kalibr's AprilGrid, markers decoded by OpenCV, corners by this package's refinement.

``marker_board`` is the skeleton both boards share; ``charuco`` and ``aprilgrid`` are its two specialisations.

Names are imported lazily (PEP 562): importing this package loads none of its modules.
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "CharucoDetector": "ccs_kornia.modules.detection.markers.charuco",
    "detect_charuco": "ccs_kornia.modules.detection.markers.charuco",
    "AprilGridDetector": "ccs_kornia.modules.detection.markers.aprilgrid",
    "detect_aprilgrid": "ccs_kornia.modules.detection.markers.aprilgrid",
    "BoardMarkers": "ccs_kornia.modules.detection.markers.marker_board",
    "MarkerBoardDetector": "ccs_kornia.modules.detection.markers.marker_board",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
