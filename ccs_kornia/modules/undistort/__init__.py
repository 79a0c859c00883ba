"""Undistortion of images for output: a calibrated camera's images (any model) to pinhole views along its optical
axis, framed within the lens's valid field.

* :mod:`~ccs_kornia.modules.undistort.valid_field`: the lens's valid field (:func:`valid_radius`);
* :mod:`~ccs_kornia.modules.undistort.view_camera`: the view's camera (:func:`view_camera_matrix`,
  :func:`horizontal_fov`);
* :mod:`~ccs_kornia.modules.undistort.undistort_image`: the image warp (:func:`undistort_image`,
  :class:`UndistortImage`, :func:`undistortion_map`);
* :mod:`~ccs_kornia.modules.undistort.fisheye_new_camera`: ``cv2.fisheye``'s new camera matrix, for comparison.

Names are imported lazily (PEP 562): importing this package loads none of its modules.
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "MAX_VIEW_ANGLE_DEG": "ccs_kornia.modules.undistort.valid_field",
    "valid_radius": "ccs_kornia.modules.undistort.valid_field",
    "view_camera_matrix": "ccs_kornia.modules.undistort.view_camera",
    "horizontal_fov": "ccs_kornia.modules.undistort.view_camera",
    "undistort_image": "ccs_kornia.modules.undistort.undistort_image",
    "undistortion_map": "ccs_kornia.modules.undistort.undistort_image",
    "UndistortImage": "ccs_kornia.modules.undistort.undistort_image",
    "fisheye_new_camera_matrix": "ccs_kornia.modules.undistort.fisheye_new_camera",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
