"""Camera models of the Levenberg–Marquardt core: projection with analytic derivatives.

* :class:`OpenCVModel`: pinhole + OpenCV polynomial distortion (``none``, ``k1k2``, ``opencv5``, ``rational``);
* :class:`CentredRadialModel`: the paper's radial distortion about a free centre;
* :class:`KannalaBrandtModel`: ``cv2.fisheye``'s Kannala–Brandt model (k1..k4), valid beyond 90 degrees;
* :class:`SplinedStereographicModel`: mrcal's splined stereographic model (a B-spline correction of the stereographic
  projection), for any lens.

The models a calibration returns are values (:data:`PINHOLE`, :data:`K1K2`, :data:`OPENCV5`, :data:`RATIONAL`,
:data:`FISHEYE`); :func:`~ccs_kornia.geometry.models.factory.camera_model` reads one from its name (files, the
command line).

Names are imported lazily (PEP 562): importing this package loads none of its modules.

Example:
    >>> from ccs_kornia.geometry.models import FISHEYE
    >>> FISHEYE.param_names[4:]
    ('k1', 'k2', 'k3', 'k4')
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "CameraModel": "ccs_kornia.geometry.models.base",
    "OpenCVModel": "ccs_kornia.geometry.models.opencv",
    "OPENCV_VARIANTS": "ccs_kornia.geometry.models.opencv",
    "CentredRadialModel": "ccs_kornia.geometry.models.centred_radial",
    "KannalaBrandtModel": "ccs_kornia.geometry.models.fisheye",
    "SplinedStereographicModel": "ccs_kornia.geometry.models.splined",
    "camera_model": "ccs_kornia.geometry.models.factory",
    "CAMERA_MODELS": "ccs_kornia.geometry.models.factory",
    "PINHOLE": "ccs_kornia.geometry.models.factory",
    "K1K2": "ccs_kornia.geometry.models.factory",
    "OPENCV5": "ccs_kornia.geometry.models.factory",
    "RATIONAL": "ccs_kornia.geometry.models.factory",
    "FISHEYE": "ccs_kornia.geometry.models.factory",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
