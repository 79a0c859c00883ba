"""A camera model of the LM core by name."""

from __future__ import annotations

from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.centred_radial import CentredRadialModel
from ccs_kornia.geometry.models.fisheye import KannalaBrandtModel
from ccs_kornia.geometry.models.opencv import OPENCV_VARIANTS, OpenCVModel

__all__ = ["camera_model"]


def camera_model(name: str, image_size: tuple[int, int] | None = None) -> CameraModel:
    """A model by name: an OpenCV variant, ``fisheye`` or ``centred_radial`` (needs ``image_size``).

    Example:
        >>> camera_model("fisheye").param_names[4:]
        ('k1', 'k2', 'k3', 'k4')
    """
    if name in OPENCV_VARIANTS:
        return OpenCVModel(name)
    if name == "fisheye":
        return KannalaBrandtModel()
    if name == "centred_radial":
        if image_size is None:
            raise ValueError("The centred_radial model needs image_size.")
        return CentredRadialModel(image_size)
    raise ValueError(f"Unknown camera model {name!r}; expected one of {sorted([*OPENCV_VARIANTS, 'fisheye', 'centred_radial'])}.")
