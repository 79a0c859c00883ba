r"""mrcal's ``.cameramodel`` files (its text format: a Python-literal dict), read into a camera and written from one.

A file holds ``lensmodel`` (mrcal's name of the model and its configuration), ``intrinsics`` (``fx, fy, cx, cy`` and
the model's values, in mrcal's order), ``extrinsics`` (``rt_cam_ref``: the reference frame in the camera's, an
axis-angle rotation and a translation) and ``imagersize``; mrcal's tools (``mrcal-show-projection-diff``,
``mrcal-reproject-image``, ...) read what :func:`cameramodel_text` writes.

The models both packages share: mrcal's ``LENSMODEL_SPLINED_STEREOGRAPHIC_...``
(:class:`~ccs_kornia.geometry.models.splined.SplinedStereographicModel`, its values unchanged), ``LENSMODEL_PINHOLE``
(``none``), ``LENSMODEL_OPENCV4`` / ``OPENCV5`` / ``OPENCV8`` (OpenCV's coefficients in OpenCV's order:
``opencv5``, or ``rational`` for eight). mrcal has no Kannala–Brandt model: a fisheye camera is not written.
"""

from __future__ import annotations

import ast
import os

import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models.factory import (
    K1K2,
    OPENCV5,
    PINHOLE,
    RATIONAL,
    camera_model,
)
from ccs_kornia.geometry.models.splined import SplinedStereographicModel

__all__ = ["cameramodel_text", "mrcal_lensmodel", "read_cameramodel", "write_cameramodel"]

#: mrcal's OpenCV models by their coefficient count, and the model of this package that holds them
_OPENCV = {"LENSMODEL_PINHOLE": (0, PINHOLE), "LENSMODEL_OPENCV4": (4, OPENCV5), "LENSMODEL_OPENCV5": (5, OPENCV5),
           "LENSMODEL_OPENCV8": (8, RATIONAL)}


def mrcal_lensmodel(camera: Camera) -> tuple[str, list[float]]:
    """mrcal's ``lensmodel`` and ``intrinsics`` of one camera.

    Raises:
        ValueError: for a model mrcal does not have (the Kannala–Brandt fisheye model).

    Example:
        >>> cam = Camera(K1K2, torch.tensor([500., 500, 320, 240, -0.1, 0.01], dtype=torch.float64), (640, 480))
        >>> mrcal_lensmodel(cam)
        ('LENSMODEL_OPENCV4', [500.0, 500.0, 320.0, 240.0, -0.1, 0.01, 0.0, 0.0])
    """
    model = camera.model
    values = [float(v) for v in camera.params[0, :4].double().tolist()]
    if isinstance(model, SplinedStereographicModel):
        return model.mrcal_name, values + [float(v) for v in camera.params[0, 4:].double().tolist()]
    if model == PINHOLE:
        return "LENSMODEL_PINHOLE", values
    if model in (K1K2, OPENCV5, RATIONAL):
        coeffs = [float(v) for v in camera.coeffs(0).double().tolist()]
        name = {K1K2: "LENSMODEL_OPENCV4", OPENCV5: "LENSMODEL_OPENCV5", RATIONAL: "LENSMODEL_OPENCV8"}[model]
        return name, values + coeffs[: {K1K2: 4, OPENCV5: 5, RATIONAL: 8}[model]] + [0.0] * (4 - len(coeffs)) * (
            model == K1K2)
    raise ValueError(f"mrcal has no {model.name} model: a .cameramodel file cannot hold this camera")


def cameramodel_text(camera: Camera, extrinsics: list[float] | None = None, note: str | None = None) -> str:
    """One camera as mrcal's ``.cameramodel`` text (``extrinsics``: mrcal's ``rt_cam_ref``, default the identity).

    Example:
        >>> from ccs_kornia.geometry.models import SplinedStereographicModel
        >>> m = SplinedStereographicModel(4, 4, 100)
        >>> p = torch.cat([torch.tensor([300., 300, 320, 240]), torch.zeros(32)]).double()
        >>> text = cameramodel_text(Camera(m, p, (640, 480)))
        >>> text.splitlines()[1]
        "    'lensmodel': 'LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=4_Ny=4_fov_x_deg=100',"
    """
    if len(camera) != 1 or camera.image_size is None:
        raise ValueError("a .cameramodel file holds one camera with its image size")
    name, values = mrcal_lensmodel(camera)
    rt = [0.0] * 6 if extrinsics is None else [float(v) for v in extrinsics]
    w, h = camera.image_size
    lines = [] if note is None else [f"# {line}" for line in note.splitlines()]
    lines += ["{", f"    'lensmodel': '{name}',", "    # intrinsics are fx,fy,cx,cy,distortion0,distortion1,....",
              f"    'intrinsics': [ {', '.join(repr(v) for v in values)},],",
              "    # extrinsics are rt_cam_ref", f"    'extrinsics': [ {', '.join(repr(v) for v in rt)},],",
              f"    'imagersize': [ {int(w)}, {int(h)},],", "}", ""]
    return "\n".join(lines)


def write_cameramodel(path: str | os.PathLike, camera: Camera, extrinsics: list[float] | None = None,
                      note: str | None = None) -> None:
    """Write :func:`cameramodel_text` to ``path``."""
    with open(path, "w", encoding="utf-8") as handle:
        handle.write(cameramodel_text(camera, extrinsics, note))


def read_cameramodel(path: str | os.PathLike) -> tuple[Camera, list[float]]:
    """The camera of an mrcal ``.cameramodel`` file and its extrinsics (``rt_cam_ref``).

    Raises:
        ValueError: one line saying what is wrong (not mrcal's format, a model this package does not have, a count
            of intrinsics that does not match the model).
    """
    try:
        with open(path, encoding="utf-8") as handle:
            text = handle.read()
    except FileNotFoundError:
        raise ValueError("no such file") from None
    except (OSError, UnicodeDecodeError) as err:
        raise ValueError(f"not a readable file ({err})") from None
    start = text.find("{")
    try:
        data = ast.literal_eval(text[start:]) if start >= 0 else None
    except (ValueError, SyntaxError, MemoryError, RecursionError):
        data = None
    if not isinstance(data, dict) or not {"lensmodel", "intrinsics", "imagersize"} <= set(data):
        raise ValueError("not an mrcal .cameramodel file (a dict with lensmodel, intrinsics and imagersize)")
    name = str(data["lensmodel"])
    values = torch.tensor([float(v) for v in data["intrinsics"]], dtype=torch.float64)
    size = tuple(int(v) for v in data["imagersize"])
    if name in _OPENCV:
        count, model = _OPENCV[name]
        if values.numel() != 4 + count:
            raise ValueError(f"{name} has {4 + count} intrinsics, the file gives {values.numel()}")
        camera = Camera(model, model.params_from(_k(values), values[4:][None] if count else None), size)
    elif name.startswith("LENSMODEL_SPLINED_STEREOGRAPHIC"):
        model = camera_model(name)
        if values.numel() != model.num_params:
            raise ValueError(f"{name} has {model.num_params} intrinsics, the file gives {values.numel()}")
        camera = Camera(model, values, size)
    else:
        raise ValueError(f"mrcal's {name} is not a model this package has (splined stereographic, pinhole, OpenCV's)")
    extrinsics = [float(v) for v in data.get("extrinsics", [0.0] * 6)]
    return camera, extrinsics


def _k(values: torch.Tensor) -> torch.Tensor:
    fx, fy, cx, cy = values[:4].tolist()
    return torch.tensor([[[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]], dtype=torch.float64)
