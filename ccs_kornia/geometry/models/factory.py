"""A camera model of the LM core by name."""

from __future__ import annotations

import functools

from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.centred_radial import CentredRadialModel
from ccs_kornia.geometry.models.fisheye import KannalaBrandtModel
from ccs_kornia.geometry.models.opencv import OPENCV_VARIANTS, OpenCVModel

__all__ = ["camera_model"]


@functools.lru_cache(maxsize=None)
def camera_model(name: str, image_size: tuple[int, int] | None = None) -> CameraModel:
    """A model by name: an OpenCV variant, ``fisheye`` or ``centred_radial`` (needs ``image_size``).

    Names are what results and files carry; this turns one into the model that answers questions about it
    (e.g. :attr:`~ccs_kornia.geometry.models.base.CameraModel.is_fisheye`). Models are stateless, so one instance per
    name is shared.

    Example:
        >>> camera_model("fisheye").param_names[4:]
        ('k1', 'k2', 'k3', 'k4')
        >>> camera_model("fisheye").is_fisheye, camera_model("k1k2").num_coeffs
        (True, 5)
    """
    if name in OPENCV_VARIANTS:
        return OpenCVModel(name)
    if name == KannalaBrandtModel.name:
        return KannalaBrandtModel()
    if name == "centred_radial":
        if image_size is None:
            raise ValueError("The centred_radial model needs image_size.")
        return CentredRadialModel(image_size)
    raise ValueError(f"Unknown camera model {name!r}; expected one of {sorted([*OPENCV_VARIANTS, 'fisheye', 'centred_radial'])}.")
