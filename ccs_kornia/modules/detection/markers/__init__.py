"""Marker boards: ChArUco and Kalibr's AprilGrid, markers decoded by OpenCV, corners by this package's refinement.

``marker_board`` is the skeleton both boards share; ``charuco`` and ``aprilgrid`` are its two specialisations. Each
board's corners come from two paths merged per corner (``corner_merge``): the marker path (each corner from the
markers OpenCV decodes beside it) and the lattice path (``lattice_path``: the heatmap network's corner lattice,
``lattice_names``: named by the markers that agree, read on its squares by ``marker_bits``).

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
    "MarkerPaths": "ccs_kornia.modules.detection.markers.corner_merge",
    "charuco_paths": "ccs_kornia.modules.detection.markers.charuco",
    "aprilgrid_paths": "ccs_kornia.modules.detection.markers.aprilgrid",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
