"""Interface shared by the camera models of the Levenberg–Marquardt core.

A model is a small stateless object: its configuration (e.g. the OpenCV variant, the image size of the
paper's radial model) is fixed at construction and nothing is stored per call, so one instance may serve
concurrent calls. It projects camera-frame points with a per-camera parameter vector and returns the
analytic derivatives the core needs: with respect to the parameters and to the camera-frame point (the
core builds the pose derivatives from the latter).

Every other map of a camera is defined once here from that projection: :meth:`CameraModel.distort` (normalized points
on the ``z = 1`` plane to pixels) is the projection of ``(x, y, 1)``; :meth:`CameraModel.undistort` inverts it by
Newton's method on the model's own derivatives (a model may give a better start, or a closed inverse);
:meth:`CameraModel.unproject` gives unit rays. Their Jacobians come from the projection's.

A model also says what it is beyond the projection (:attr:`CameraModel.is_fisheye`) and how its coefficients sit in
OpenCV's layout, the one results and files store (:attr:`CameraModel.num_coeffs`, :meth:`CameraModel.opencv_coeffs`),
so that callers ask the model instead of testing its name. Models compare equal by kind and configuration, and
``str(model)`` is the name files carry (:func:`~ccs_kornia.geometry.models.factory.camera_model` parses it back).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from ccs_kornia.runtime.checks import check_shape, check_tensor

__all__ = ["CameraModel", "check_projection_inputs", "broadcast_params", "unit_columns", "solve_2x2"]

#: Newton steps of :meth:`CameraModel.undistort` after its start (quadratic convergence: a good start needs 2-3)
UNDISTORT_NEWTON_STEPS = 4


def check_projection_inputs(points: torch.Tensor, params: torch.Tensor, num_params: int) -> None:
    """Shape checks shared by the models: points :math:`(C, *, 3)`, params :math:`(C, P)`."""
    check_shape(points, ["*", "N", "3"], "points must be (C, *, 3)")
    check_tensor(params, "params", ["1", num_params], ["C", num_params], C=points.shape[0])


class CameraModel:
    """Base class: ``project(points, params, jacobians)`` and the parameter layout.

    Every model's parameter vector starts with ``fx, fy, cx, cy``; the distortion coefficients follow.
    """

    #: short name, e.g. ``"opencv5"`` or ``"fisheye"``: what files carry (``str(model)``)
    name: str = ""
    #: names of the parameters, in order
    param_names: tuple[str, ...] = ()

    def _key(self) -> tuple:
        """What makes two instances the same model (its kind, name and configuration)."""
        return (self.name,)

    def __eq__(self, other: object) -> bool:
        return type(self) is type(other) and self._key() == other._key()  # type: ignore[attr-defined]

    def __hash__(self) -> int:
        return hash((type(self).__name__, self._key()))

    def __str__(self) -> str:
        return self.name

    @property
    def num_params(self) -> int:
        """Number of parameters ``P``."""
        return len(self.param_names)

    @property
    def is_fisheye(self) -> bool:
        """A fisheye model (``cv2.fisheye``'s functions; angles at and beyond 90 degrees project)."""
        return False

    @property
    def local_support(self) -> bool:
        """Most parameters act on a small part of the image only (a spline's control points): the model gives them in
        local form (``local_columns``: per point the pairs of parameters it depends on, the first moving ``u``, the
        second ``v``, and their derivatives), which the LM core assembles without a column per parameter."""
        return False

    @property
    def num_local(self) -> int:
        """Parameters in local form (the last ones; 0 for a model without :attr:`local_support`)."""
        return 0

    def straight(self, params: torch.Tensor) -> torch.Tensor:
        """:math:`(C,)` bool: with these parameters :math:`(C, P)` the model images straight lines straight (its
        distortion terms all zero); a model whose projection is not a pinhole's at any coefficients overrides it."""
        return (params[:, 4:] == 0).all(-1)

    def visible(self, points: torch.Tensor) -> torch.Tensor:
        """Which camera-frame points :math:`(*, 3)` the model images, :math:`(*)` bool: a pinhole projection only
        those in front of the camera (a fisheye model overrides it: it sees beyond 90 degrees)."""
        return points[..., 2] > 1e-6

    def monotonic_radius(self, params: torch.Tensor, max_angle: float) -> torch.Tensor:
        """How far from the axis, as a radius on the normalized (``z = 1``) plane, the model's radial mapping keeps
        increasing: beyond it several directions share one image radius (undistorting there folds the image back).

        Each model gives its own rule (every model of the package overrides this); the result is at most
        ``tan(max_angle)``.

        Args:
            params: :math:`(C, P)` parameters.
            max_angle: the widest angle from the axis asked for, in radians (below ``pi / 2``).

        Returns:
            :math:`(C,)` radius (``tan`` of an angle from the axis), in the parameters' dtype.
        """
        raise NotImplementedError(f"{type(self).__name__} has no rule for the range where it is monotonic.")

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
            >>> from ccs_kornia.geometry.models import FISHEYE, K1K2
            >>> K1K2.opencv_coeffs([-0.3, 0.1]).tolist()
            [-0.3, 0.1, 0.0, 0.0, 0.0]
            >>> FISHEYE.opencv_coeffs([]).shape
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

    def distort(
        self, normalized: torch.Tensor, params: torch.Tensor, jacobians: bool = False
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Normalized points on the ``z = 1`` plane to pixels: the projection of ``(x, y, 1)``.

        For a fisheye, ``(x, y)`` is ``tan(theta) (cos(phi), sin(phi))`` (``cv2.fisheye``'s undistorted points).

        Args:
            normalized: :math:`(C, *, 2)` points.
            params: :math:`(C, P)` parameters.
            jacobians: also return ``d pixel / d (x, y)`` :math:`(C, *, 2, 2)` (rows ``u, v``).

        Returns:
            pixels :math:`(C, *, 2)` (and the Jacobian).
        """
        points = torch.cat([normalized, torch.ones_like(normalized[..., :1])], -1)
        uv, _, dx = self.columns(points, params, jacobians)
        if not jacobians:
            return uv
        return uv, torch.stack([dx[0].expand(uv.shape), dx[1].expand(uv.shape)], -1)

    def undistort_start(self, pixels: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """Where :meth:`undistort`'s Newton steps start: the pinhole inverse (a model with a better start overrides
        it); pixels :math:`(C, *, 2)` in, normalized points :math:`(C, *, 2)` out."""
        p = broadcast_params(params, pixels)
        return (pixels - p[..., 2:4]) / p[..., 0:2]

    def undistort(
        self, pixels: torch.Tensor, params: torch.Tensor, jacobians: bool = False
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Pixels to normalized points on the ``z = 1`` plane, the inverse of :meth:`distort` (``cv2.undistortPoints``).

        Newton's method on the model's own derivatives from :meth:`undistort_start`, each step bounded to one unit of
        the normalized plane (outside the model's monotonic range no inverse exists; the steps then stay finite).

        Args:
            pixels: :math:`(C, *, 2)` observed pixels.
            params: :math:`(C, P)` parameters.
            jacobians: also return ``d (x, y) / d pixel`` :math:`(C, *, 2, 2)`, the inverse of :meth:`distort`'s.

        Returns:
            normalized points :math:`(C, *, 2)` (and the Jacobian).
        """
        xy = self.undistort_start(pixels, params)
        for _ in range(UNDISTORT_NEWTON_STEPS):
            uv, J = self.distort(xy, params, jacobians=True)
            xy = xy - solve_2x2(J, uv - pixels).clamp(-1.0, 1.0)
        if not jacobians:
            return xy
        return xy, torch.linalg.inv(self.distort(xy, params, jacobians=True)[1])

    def unproject(
        self, pixels: torch.Tensor, params: torch.Tensor, jacobians: bool = False
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Pixels to unit viewing rays, the inverse of the projection (a fisheye's reach beyond 90 degrees).

        Args:
            pixels: :math:`(C, *, 2)` observed pixels.
            params: :math:`(C, P)` parameters.
            jacobians: also return ``d ray / d pixel`` :math:`(C, *, 3, 2)`: the ray moves on the unit sphere, so its
                derivative solves ``[d uv / d X; ray^T] d ray = [d uv; 0]``.

        Returns:
            rays :math:`(C, *, 3)` (and the Jacobian).
        """
        xy = self.undistort(pixels, params)
        rays = torch.nn.functional.normalize(torch.cat([xy, torch.ones_like(xy[..., :1])], -1), dim=-1)
        return (rays, self.ray_jacobian(rays, params)) if jacobians else rays

    def ray_jacobian(self, rays: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """``d ray / d pixel`` :math:`(C, *, 3, 2)` of :meth:`unproject` at unit rays :math:`(C, *, 3)`."""
        uv, _, dx = self.columns(rays, params, True)
        Jx = torch.stack([c.expand(uv.shape) for c in dx], -1)  # (C, *, 2, 3)
        A = torch.cat([Jx, rays.unsqueeze(-2)], -2)  # (C, *, 3, 3)
        return torch.linalg.inv(A)[..., :2]

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"


def solve_2x2(J: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """``J^-1 r`` for :math:`(*, 2, 2)` matrices and :math:`(*, 2)` vectors in closed form (a determinant below
    ``1e-12`` in size is held there, so a singular point gives a large finite step, not a NaN)."""
    a, b, c, d = J[..., 0, 0], J[..., 0, 1], J[..., 1, 0], J[..., 1, 1]
    det = a * d - b * c
    det = torch.where(det.abs() < 1e-12, torch.full_like(det, 1e-12), det)
    return torch.stack([d * r[..., 0] - b * r[..., 1], a * r[..., 1] - c * r[..., 0]], -1) / det.unsqueeze(-1)


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
