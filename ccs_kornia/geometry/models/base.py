"""Interface shared by the camera models of the Levenberg–Marquardt core.

A model is a small stateless object: its configuration (e.g. the OpenCV variant, the image size of the
paper's radial model) is fixed at construction and nothing is stored per call, so one instance may serve
concurrent calls. It projects camera-frame points with a per-camera parameter vector and returns the
analytic derivatives the core needs: with respect to the parameters and to the camera-frame point (the
core builds the pose derivatives from the latter).

A model also says what it is beyond the projection (:attr:`CameraModel.is_fisheye`) and how its coefficients sit in
OpenCV's layout, the one results and files store (:attr:`CameraModel.num_coeffs`, :meth:`CameraModel.opencv_coeffs`),
so that callers ask the model instead of testing its name.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

__all__ = ["CameraModel", "check_projection_inputs", "broadcast_params", "unit_columns"]


def check_projection_inputs(points: torch.Tensor, params: torch.Tensor, num_params: int) -> None:
    """Shape checks shared by the models: points :math:`(C, *, 3)`, params :math:`(C, P)`."""
    if not isinstance(points, torch.Tensor) or points.dim() < 2 or points.shape[-1] != 3:
        raise ValueError(f"points must be (C, *, 3), got {tuple(getattr(points, 'shape', ()))}.")
    if not isinstance(params, torch.Tensor) or params.dim() != 2 or params.shape[-1] != num_params:
        raise ValueError(f"params must be (C, {num_params}), got {tuple(getattr(params, 'shape', ()))}.")
    if params.shape[0] not in (1, points.shape[0]):
        raise ValueError(f"params has {params.shape[0]} cameras but points has {points.shape[0]}.")


class CameraModel:
    """Base class: ``project(points, params, jacobians)`` and the parameter layout.

    Every model's parameter vector starts with ``fx, fy, cx, cy``; the distortion coefficients follow.
    """

    #: short name, e.g. ``"opencv5"`` or ``"fisheye"``
    name: str = ""
    #: names of the parameters, in order
    param_names: tuple[str, ...] = ()

    @property
    def num_params(self) -> int:
        """Number of parameters ``P``."""
        return len(self.param_names)

    @property
    def is_fisheye(self) -> bool:
        """A fisheye model (``cv2.fisheye``'s functions; angles at and beyond 90 degrees project)."""
        return False

    @property
    def opencv_family(self) -> str:
        """Which OpenCV functions take the coefficients: ``"fisheye"`` (``cv2.fisheye``) or ``"opencv"`` (``cv2``), as
        OpenCV's calibration files name them (``distortion_model``)."""
        return "fisheye" if self.is_fisheye else "opencv"

    @property
    def coeff_index(self) -> tuple[int, ...]:
        """Where the model's coefficients (the parameters after ``fx, fy, cx, cy``) sit in OpenCV's layout."""
        raise NotImplementedError(f"{type(self).__name__} has no OpenCV coefficient layout.")

    @property
    def num_coeffs(self) -> int:
        """Coefficients a calibration with this model stores, in OpenCV's layout."""
        raise NotImplementedError(f"{type(self).__name__} has no OpenCV coefficient layout.")

    @property
    def max_coeffs(self) -> int:
        """Most coefficients of OpenCV's layout for this kind of model (shorter vectors mean trailing zeros)."""
        raise NotImplementedError(f"{type(self).__name__} has no OpenCV coefficient layout.")

    def opencv_length(self, n: int) -> int:
        """How many coefficients OpenCV's functions take for ``n`` given (``n`` padded with zeros)."""
        raise NotImplementedError(f"{type(self).__name__} has no OpenCV coefficient layout.")

    def opencv_coeffs(self, coeffs: Any) -> Any:
        """Coefficients in this model's OpenCV layout padded with zeros to a length OpenCV's functions take
        (:meth:`opencv_length`): a tensor :math:`(*, D)` stays a tensor, anything else (a list, an array) becomes a
        float64 array :math:`(D',)`.

        Example:
            >>> from ccs_kornia.geometry.models import camera_model
            >>> camera_model("k1k2").opencv_coeffs([-0.3, 0.1]).tolist()
            [-0.3, 0.1, 0.0, 0.0, 0.0]
            >>> camera_model("fisheye").opencv_coeffs([]).shape
            (4,)
        """
        if isinstance(coeffs, torch.Tensor):
            n = coeffs.shape[-1]
            return torch.nn.functional.pad(coeffs, [0, self.opencv_length(n) - n])
        values = np.asarray(coeffs if coeffs is not None else [], dtype=np.float64).reshape(-1)
        return np.concatenate([values, np.zeros(self.opencv_length(values.size))[values.size:]])

    def coeffs_from(self, params: torch.Tensor) -> torch.Tensor:
        """The stored coefficients :math:`(C, D)` (OpenCV layout, :attr:`num_coeffs`) of params :math:`(C, P)`."""
        d = params.new_zeros(params.shape[0], self.num_coeffs)
        if self.coeff_index:
            d[:, list(self.coeff_index)] = params[:, 4:]
        return d

    def default_free(self) -> list[bool]:
        """Which parameters are estimated by default (all of them unless a model says otherwise)."""
        return [True] * self.num_params

    def columns(self, points: torch.Tensor, params: torch.Tensor, jacobians: bool = True) -> tuple:
        """Projection and derivatives in column form (what the LM core consumes; no stacking copies).

        A column holds the derivative of both image coordinates, ``(d u, d v)`` in its last dim, so one tensor
        op computes the two rows of the Jacobian at once.

        Args:
            points: :math:`(C, *, 3)` camera-frame points.
            params: :math:`(C, P)` parameters.
            jacobians: also return the derivative columns.

        Returns:
            ``(uv, d_dp, d_dX)``: uv :math:`(C, *, 2)`; ``d_dp`` a list of ``P`` tensors and ``d_dX`` a list of 3
            tensors (with respect to the camera-frame point), each :math:`(C, *, 2)` or broadcastable to it;
            ``(uv, None, None)`` without ``jacobians``.
        """
        raise NotImplementedError

    def project(
        self, points: torch.Tensor, params: torch.Tensor, jacobians: bool = True
    ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        """Project camera-frame points.

        Args:
            points: :math:`(C, *, 3)` camera-frame points.
            params: :math:`(C, P)` parameters.
            jacobians: also return the derivatives.

        Returns:
            uv :math:`(C, *, 2)`, d uv / d params :math:`(C, *, 2, P)` and d uv / d points :math:`(C, *, 2, 3)`
            (``None`` without ``jacobians``).
        """
        uv, dp, dx = self.columns(points, params, jacobians)
        if not jacobians:
            return uv, None, None
        return uv, torch.stack([c.expand(uv.shape) for c in dp], -1), torch.stack([c.expand(uv.shape) for c in dx], -1)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"


def broadcast_params(params: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """View params :math:`(C, P)` as :math:`(C, 1, ..., 1, P)` against points :math:`(C, *, 3)`."""
    return params.reshape(params.shape[0], *([1] * (points.dim() - 2)), params.shape[-1])


_UNITS: dict[tuple, tuple[torch.Tensor, torch.Tensor]] = {}


def unit_columns(like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The constant columns ``(1, 0)`` and ``(0, 1)`` (derivatives of ``u, v`` by ``cx`` and ``cy``).

    The same two tensors are returned for a dtype and device (never written to), so the LM core can recognise
    them and expand them once per solve.
    """
    key = (like.dtype, like.device)
    if key not in _UNITS:
        with torch.inference_mode(False):
            e = torch.eye(2, dtype=like.dtype, device=like.device)
        _UNITS[key] = (e[0], e[1])
    return _UNITS[key]
