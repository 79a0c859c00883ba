"""Circle grids: OpenCV's symmetric and asymmetric grids of dots and ROS-Industrial's modified grid (a larger dot at
the origin), dark dots on light or the inverse.

``dot_moments`` measures each dot (the centre and area of its image from grey-level moments), ``circle_grid`` finds
the grid and orders its dots, ``centre_bias`` corrects the centres for perspective and lens distortion once a camera
and the board's poses are known (the centre of a dot's image is not the image of its centre).

Names are imported lazily (PEP 562): importing this package loads none of its modules.
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "dot_moments": "ccs_kornia.modules.detection.circles.dot_moments",
    "DotMoments": "ccs_kornia.modules.detection.circles.dot_moments",
    "CircleGridDetector": "ccs_kornia.modules.detection.circles.circle_grid",
    "detect_circle_grid": "ccs_kornia.modules.detection.circles.circle_grid",
    "order_marked_origin": "ccs_kornia.modules.detection.circles.circle_grid",
    "centre_bias": "ccs_kornia.modules.detection.circles.centre_bias",
    "dot_radii": "ccs_kornia.modules.detection.circles.centre_bias",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
