"""Undistortion of images for output: OpenCV and Kannala-Brandt lenses to pinhole views, and the camera of the
undistorted view (framed within the lens's valid field).

Names are imported lazily (PEP 562): importing this package loads none of its modules.
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "opencv_undistort_image": "ccs_kornia.modules.undistort.opencv_warp",
    "opencv_view_camera_matrix": "ccs_kornia.modules.undistort.opencv_warp",
    "fisheye_undistort_image": "ccs_kornia.modules.undistort.fisheye_warp",
    "fisheye_view_camera_matrix": "ccs_kornia.modules.undistort.fisheye_warp",
    "view_camera_matrix": "ccs_kornia.modules.undistort.view_camera",
    "horizontal_fov": "ccs_kornia.modules.undistort.view_camera",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
