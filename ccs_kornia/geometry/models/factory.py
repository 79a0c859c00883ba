"""The camera models by value (:data:`PINHOLE`, :data:`K1K2`, :data:`OPENCV5`, :data:`RATIONAL`, :data:`FISHEYE`) and
by name (:func:`camera_model`, the one place a name becomes a model: files and the command line carry names)."""

from __future__ import annotations

import functools

from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.centred_radial import CentredRadialModel
from ccs_kornia.geometry.models.fisheye import KannalaBrandtModel
from ccs_kornia.geometry.models.opencv import OpenCVModel
from ccs_kornia.geometry.models.splined import SPLINE_NAME, SplinedStereographicModel

__all__ = ["CAMERA_MODELS", "FISHEYE", "K1K2", "OPENCV5", "PINHOLE", "RATIONAL", "camera_model"]

#: the pinhole camera without lens distortion (OpenCV's model with every coefficient zero; files name it ``none``)
PINHOLE = OpenCVModel("none")
#: OpenCV's model with two radial terms
K1K2 = OpenCVModel("k1k2")
#: OpenCV's default model ``k1, k2, p1, p2, k3``
OPENCV5 = OpenCVModel("opencv5")
#: OpenCV's rational model ``k1 .. k6`` with the tangential terms
RATIONAL = OpenCVModel("rational")
#: ``cv2.fisheye``'s Kannala–Brandt model ``k1 .. k4``
FISHEYE = KannalaBrandtModel()
#: the models a calibration returns, by their names
CAMERA_MODELS: dict[str, CameraModel] = {m.name: m for m in (PINHOLE, K1K2, OPENCV5, RATIONAL, FISHEYE)}


@functools.lru_cache(maxsize=None)
def camera_model(name: str, image_size: tuple[int, int] | None = None) -> CameraModel:
    """The model a name stands for: an OpenCV variant, ``fisheye``, ``centred_radial`` (needs ``image_size``) or a
    splined stereographic model with its configuration (``splined_stereographic_order=3_Nx=30_Ny=20_fov_x_deg=170``,
    or mrcal's ``LENSMODEL_SPLINED_STEREOGRAPHIC_...``).

    Names are what files and the command line carry; this is where they become models (the package passes models).

    Example:
        >>> camera_model("fisheye") == FISHEYE, camera_model("k1k2").num_coeffs
        (True, 5)
        >>> camera_model("fisheye").param_names[4:]
        ('k1', 'k2', 'k3', 'k4')
    """
    if name in CAMERA_MODELS:
        return CAMERA_MODELS[name]
    if name == "centred_radial":
        if image_size is None:
            raise ValueError("The centred_radial model needs image_size.")
        return CentredRadialModel(image_size)
    if name.startswith((SPLINE_NAME, "LENSMODEL_SPLINED_STEREOGRAPHIC")):
        return SplinedStereographicModel.from_name(name)
    raise ValueError(f"Unknown camera model {name!r}; expected one of {', '.join([*CAMERA_MODELS, 'centred_radial'])} or "
                     f"{SPLINE_NAME}_order=3_Nx=.._Ny=.._fov_x_deg=...")
