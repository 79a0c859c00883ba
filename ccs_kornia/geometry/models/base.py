"""Interface shared by the camera models of the Levenberg–Marquardt core.

A model is a small stateless object: its configuration (e.g. the OpenCV variant, the image size of the
paper's radial model) is fixed at construction and nothing is stored per call, so one instance may serve
concurrent calls. It projects camera-frame points with a per-camera parameter vector and returns the
analytic derivatives the core needs: with respect to the parameters and to the camera-frame point (the
core builds the pose derivatives from the latter).
"""

from __future__ import annotations

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
