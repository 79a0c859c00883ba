"""The camera value (:class:`Camera`): what every stage passes for a camera, and the projection it shares.

A :class:`Camera` is what the package passes wherever it means a camera: its model as a type
(:mod:`ccs_kornia.geometry.models`, never a name), its parameters and its image size, batched over cameras. Its
maps (project, unproject, distort, undistort and their Jacobians) are each model's single definition.

Conventions (see ``docs/architecture.md``):

* pixels: the centre of the top-left pixel is ``(0, 0)``, x to the right, y down (OpenCV and
  ``kornia.geometry.create_meshgrid(..., normalized_coordinates=False)``);
* board: ``cols x rows`` inner corners; object point ``n = j * cols + i`` is ``(i * s, j * s, 0)``
  (:mod:`ccs_kornia.geometry.board_points`);
* poses: OpenCV's ``rvec`` (axis-angle, world-to-camera) and ``tvec``;
* OpenCV distortion: ``(k1, k2, p1, p2, k3)`` (``opencv5``) or ``(k1, k2, p1, p2, k3, k4, k5, k6)``
  (``rational``), applied on the normalized plane as ``cv2.projectPoints`` and kornia's ``distort_points`` do
  (:class:`~ccs_kornia.geometry.models.opencv.OpenCVModel`; its inverse starts from kornia's ``undistort_points``);
* Kannala-Brandt fisheye (``cv2.fisheye``): ``theta = atan2(r, z)``,
  ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``, ``D = (k1, k2, k3, k4)``;
* the paper's radial model (used for training data and the distortion CNN) lives in
  :mod:`ccs_kornia.geometry.radial`.

This module imports nothing of ``ccs_kornia`` but the camera models and the shared shape checks.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from kornia.geometry.conversions import (
    axis_angle_to_rotation_matrix,
    rotation_matrix_to_axis_angle,
)

from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.factory import OPENCV5, PINHOLE, RATIONAL
from ccs_kornia.runtime.checks import broadcast_shapes, check_shape, check_tensor

__all__ = [
    "Camera",
    "axis_angle_to_rotation_matrix",
    "intrinsics_matrix",
    "intrinsics_params",
    "project_points",
    "rotation_matrix_to_axis_angle",
    "transform_points_rt",
]


def intrinsics_matrix(params: torch.Tensor) -> torch.Tensor:
    """Build ``K`` from ``(..., 4)`` parameters ``(fx, fy, cx, cy)``; returns ``(..., 3, 3)``.

    Example:
        >>> intrinsics_matrix(torch.tensor([500., 510., 320., 240.]))
        tensor([[500.,   0., 320.],
                [  0., 510., 240.],
                [  0.,   0.,   1.]])
    """
    check_tensor(params, "params", ["*", "4"], what="intrinsics (fx, fy, cx, cy)")
    fx, fy, cx, cy = params.unbind(-1)
    z, o = torch.zeros_like(fx), torch.ones_like(fx)
    return torch.stack([fx, z, cx, z, fy, cy, z, z, o], -1).reshape(*params.shape[:-1], 3, 3)


def intrinsics_params(K: torch.Tensor) -> torch.Tensor:
    """``(..., 3, 3)`` camera matrix to ``(..., 4)`` parameters ``(fx, fy, cx, cy)``."""
    check_tensor(K, "K", ["*", "3", "3"], what="camera matrices")
    return torch.stack([K[..., 0, 0], K[..., 1, 1], K[..., 0, 2], K[..., 1, 2]], -1)


def transform_points_rt(points: torch.Tensor, rvec: torch.Tensor, tvec: torch.Tensor) -> torch.Tensor:
    """Apply ``X_cam = R(rvec) X + tvec``.

    Args:
        points: :math:`(*, N, 3)` world points.
        rvec: :math:`(*, 3)` axis-angle rotation.
        tvec: :math:`(*, 3)` translation.

    Returns:
        :math:`(*, N, 3)` camera-frame points.
    """
    R = axis_angle_to_rotation_matrix(rvec.reshape(-1, 3)).reshape(*rvec.shape[:-1], 3, 3)
    return points @ R.transpose(-1, -2) + tvec.unsqueeze(-2)


def _pad_opencv(dist: torch.Tensor) -> torch.Tensor:
    n = dist.shape[-1]
    if n in (4, 5, 8):
        return dist
    if n < 4:
        return torch.nn.functional.pad(dist, [0, 4 - n])
    raise ValueError(f"OpenCV distortion needs 0, 4, 5 or 8 coefficients, got {n}.")


def project_points(
    points: torch.Tensor,
    K: torch.Tensor,
    dist: torch.Tensor | None = None,
    rvec: torch.Tensor | None = None,
    tvec: torch.Tensor | None = None,
) -> torch.Tensor:
    """Project 3D points with a pinhole camera and OpenCV distortion (as ``cv2.projectPoints``), in OpenCV's terms:
    the functional form of :meth:`Camera.project` for ``K`` (zero skew) and OpenCV's coefficients.

    Args:
        points: :math:`(*, N, 3)` points (world frame if ``rvec``/``tvec`` given, else camera frame).
        K: :math:`(*, 3, 3)` camera matrix.
        dist: :math:`(*, D)` OpenCV coefficients, ``D`` at most 5 (the rest zero) or 8; ``None`` for no distortion.
        rvec: :math:`(*, 3)` axis-angle rotation world-to-camera.
        tvec: :math:`(*, 3)` translation.

    Returns:
        :math:`(*, N, 2)` pixel coordinates.

    Example:
        >>> K = torch.tensor([[500., 0, 320], [0, 500, 240], [0, 0, 1]])
        >>> project_points(torch.tensor([[0.1, 0.0, 1.0]]), K)
        tensor([[370., 240.]])
    """
    check_tensor(points, "points", ["*", "N", "3"])
    check_tensor(K, "K", ["*", "3", "3"], what="camera matrices")
    if rvec is not None:
        if tvec is None:
            raise ValueError("rvec given without tvec.")
        points = transform_points_rt(points, rvec, tvec)
    # the model of the coefficients' count (up to 5: OpenCV's default layout, the rest zero; 8: its rational model);
    # applied even when every coefficient is zero, so the gradients at the usual zero start are those of the model
    n = 0 if dist is None else dist.shape[-1]
    if n > 8 or n in (6, 7):
        raise ValueError(f"OpenCV distortion needs at most 5, or 8, coefficients, got {n}.")
    model = PINHOLE if n == 0 else (RATIONAL if n == 8 else OPENCV5)
    coeffs = points.new_zeros(0) if dist is None else torch.nn.functional.pad(dist.to(points.dtype), [0, 5 - n] if n < 5 else [0, 0])
    batch = broadcast_shapes(points.shape[:-2], K.shape[:-2], coeffs.shape[:-1])
    N = points.shape[-2]
    params = torch.cat([intrinsics_params(K.to(points.dtype)).expand(*batch, 4),
                        coeffs.expand(*batch, coeffs.shape[-1])], -1).reshape(-1, model.num_params)
    uv = model.project(points.expand(*batch, N, 3).reshape(-1, N, 3), params, jacobians=False)[0]
    return uv.reshape(*batch, N, 2)


# ----------------------------------------------------------------------------------------------
# The camera value
# ----------------------------------------------------------------------------------------------

ImageSize = tuple[int, int]


def _image_sizes(image_size, count: int) -> tuple[ImageSize | None, ...]:
    if image_size is None:
        return (None,) * count
    if len(image_size) == 2 and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in image_size):
        image_size = [image_size] * count
    sizes = tuple(None if s is None else (int(s[0]), int(s[1])) for s in image_size)
    if len(sizes) != count:
        raise ValueError(f"image_size must be (W, H) or one (W, H) per camera ({count}), got {len(sizes)}.")
    if any(s is not None and min(s) <= 0 for s in sizes):
        raise ValueError(f"image sizes must be positive (W, H), got {sizes}.")
    return sizes


class Camera:
    r"""``C`` cameras as one value: each one's model (a type), its parameters and its image size.

    The parameters are each model's vector (``fx, fy, cx, cy`` then its coefficients, zero skew), the vector the
    Levenberg–Marquardt core estimates; :attr:`K` and :attr:`dist` give them in OpenCV's layout, so they drop into
    ``cv2`` (``cv2.fisheye`` for a fisheye) unchanged. Cameras of different models share one value (a rig, the
    cameras of ``--model auto``): their parameter rows are NaN-padded to the longest, and every map runs once per
    model.

    Args:
        model: one :class:`~ccs_kornia.geometry.models.base.CameraModel` for every camera, or one per camera.
        params: :math:`(C, P)` parameters (``P`` the longest model's count; shorter rows NaN-padded), or :math:`(P,)`
            for one camera.
        image_size: ``(W, H)`` for every camera, one per camera, or ``None`` where unknown.

    Example:
        >>> from ccs_kornia.geometry.models import OPENCV5
        >>> K = torch.tensor([[500., 0, 320], [0, 500, 240], [0, 0, 1]], dtype=torch.float64)
        >>> cam = Camera.from_opencv(OPENCV5, K, torch.tensor([-0.2, 0.05, 0, 0, 0], dtype=torch.float64), (640, 480))
        >>> uv = cam.project(torch.tensor([[[0.1, 0.0, 1.0]]], dtype=torch.float64))
        >>> uv.tolist(), cam.undistort(uv).round(decimals=12).tolist()
        ([[[369.90025, 240.0]]], [[[0.1, 0.0]]])
        >>> cam.model, cam.K.shape, cam.dist.shape, cam.image_size
        (OpenCVModel('opencv5'), torch.Size([1, 3, 3]), torch.Size([1, 5]), (640, 480))
    """

    def __init__(self, model, params: torch.Tensor, image_size=None) -> None:
        check_tensor(params, "params", ["C", "P"], ["P"], what="camera parameters")
        params = params[None] if params.dim() == 1 else params
        count = params.shape[0]
        models = tuple(model) if isinstance(model, (tuple, list)) else (model,) * count
        if not all(isinstance(m, CameraModel) for m in models):
            bad = next(m for m in models if not isinstance(m, CameraModel))
            raise TypeError(f"a Camera's model must be a CameraModel (e.g. ccs_kornia.geometry.models.OPENCV5), not "
                            f"{bad!r}; names are read by ccs_kornia.geometry.models.camera_model.")
        if len(models) != count:
            raise ValueError(f"Camera has {count} parameter rows but {len(models)} models.")
        width = max((m.num_params for m in models), default=0)
        if count:
            check_tensor(params, "params", ["C", width], what=f"for {_names(models)}")
        self.models: tuple = models
        self.params: torch.Tensor = params
        self.image_sizes: tuple[ImageSize | None, ...] = _image_sizes(image_size, count)

    # -- construction ------------------------------------------------------------------------

    @classmethod
    def from_opencv(cls, model, K: torch.Tensor, dist: torch.Tensor | None = None, image_size=None) -> Camera:
        """Cameras from OpenCV's ``K`` :math:`(C, 3, 3)` / :math:`(3, 3)` and coefficients :math:`(C, D)` / :math:`(D,)`
        in the model's OpenCV layout (fewer: the rest zero; ``cv2.fisheye``'s ``k1..k4`` for a fisheye).

        Coefficients the model does not have must be zero (``k1k2``'s ``p1, p2, k3``): they would be dropped.
        Only one model here; :meth:`cat` joins cameras of several.
        """
        check_tensor(K, "K", ["C", "3", "3"], ["3", "3"])
        K = K[None] if K.dim() == 2 else K
        if dist is not None:
            dist = torch.as_tensor(dist, dtype=K.dtype, device=K.device)
            dist = dist[None] if dist.dim() == 1 else dist
            if dist.dim() != 2 or dist.shape[-1] > model.max_coeffs:
                raise ValueError(f"{model.name} takes (C, D) coefficients with D <= {model.max_coeffs}, got "
                                 f"{tuple(dist.shape)}.")
            extra = [i for i in range(dist.shape[-1]) if i not in model.coeff_index]
            if extra and bool((dist[:, extra].ne(0) & dist[:, extra].isfinite()).any()):
                raise ValueError(f"the {model.name} model has no coefficient at place(s) {extra} of OpenCV's layout; "
                                 f"they must be zero.")
        return cls(model, model.params_from(K, dist), image_size)

    @classmethod
    def cat(cls, cameras: Sequence[Camera]) -> Camera:
        """One value of the cameras of ``cameras``, in order (any models)."""
        if not cameras:
            raise ValueError("Camera.cat needs at least one camera.")
        models = tuple(m for c in cameras for m in c.models)
        width = max(m.num_params for m in models)
        rows = [c.params if c.params.shape[-1] == width else torch.nn.functional.pad(
            c.params, [0, width - c.params.shape[-1]], value=float("nan")) for c in cameras]
        first = cameras[0].params
        rows = [r.to(device=first.device, dtype=first.dtype) for r in rows]
        return cls(models, torch.cat(rows), [s for c in cameras for s in c.image_sizes])

    def with_params(self, params: torch.Tensor) -> Camera:
        """The same models and sizes with other parameters :math:`(C, P)` (e.g. a solver's)."""
        return Camera(self.models, params, self.image_sizes)

    # -- what it holds ------------------------------------------------------------------------

    def __len__(self) -> int:
        return self.params.shape[0]

    @property
    def model(self):
        """The model of every camera (an error where the cameras have several: see :attr:`models`)."""
        if len(set(self.models)) != 1:
            raise ValueError(f"these cameras have several models ({_names(self.models)}): use Camera.models.")
        return self.models[0]

    @property
    def uniform(self) -> bool:
        """Every camera has the same model."""
        return len(set(self.models)) <= 1

    @property
    def image_size(self) -> ImageSize | None:
        """The image size ``(W, H)`` of every camera (an error where they differ: see :attr:`image_sizes`)."""
        if len(set(self.image_sizes)) > 1:
            raise ValueError(f"these cameras have several image sizes ({self.image_sizes}): use Camera.image_sizes.")
        return self.image_sizes[0] if self.image_sizes else None

    @property
    def device(self) -> torch.device:
        return self.params.device

    @property
    def dtype(self) -> torch.dtype:
        return self.params.dtype

    @property
    def K(self) -> torch.Tensor:
        """:math:`(C, 3, 3)` camera matrices (zero skew; all NaN for a camera without intrinsics, e.g. one that failed)."""
        K = intrinsics_matrix(self.params[:, :4])
        return torch.where(self.params[:, :4].isnan().any(-1)[:, None, None], float("nan"), K)

    @property
    def dist(self) -> torch.Tensor:
        """:math:`(C, D)` coefficients in OpenCV's layout (:attr:`~ccs_kornia.geometry.models.base.CameraModel.num_coeffs`
        of the model; cameras of several models: NaN-padded to the widest)."""
        if self.uniform:
            return self.model.coeffs_from(self.params) if self.models else self.params[:, :0]
        width = max(m.num_coeffs for m in self.models)
        out = self.params.new_full((len(self), width), float("nan"))
        for model, idx in self._groups():
            d = model.coeffs_from(self.params[idx, : model.num_params])
            out[idx, : d.shape[-1]] = d
        return out

    def coeffs(self, index: int) -> torch.Tensor:
        """Camera ``index``'s coefficients :math:`(D,)` in its model's OpenCV layout (no padding)."""
        model = self.models[index]
        return model.coeffs_from(self.params[index : index + 1, : model.num_params])[0]

    def __getitem__(self, index) -> Camera:
        """Cameras ``index`` (an int, a slice, a list or a tensor of indices, or a bool mask), camera dim kept."""
        if isinstance(index, int):
            index = [index]
        idx = torch.arange(len(self))[index] if not isinstance(index, torch.Tensor) else (
            index.nonzero().flatten().cpu() if index.dtype == torch.bool else index.cpu())
        picks = idx.reshape(-1).tolist()
        models = tuple(self.models[i] for i in picks)
        width = max((m.num_params for m in models), default=self.params.shape[-1])
        return Camera(models, self.params[idx.to(self.device)][:, :width], [self.image_sizes[i] for i in picks])

    def to(self, device=None, dtype: torch.dtype | None = None) -> Camera:
        return Camera(self.models, self.params.to(device=device, dtype=dtype), self.image_sizes)

    def detach(self) -> Camera:
        return Camera(self.models, self.params.detach(), self.image_sizes)

    def clone(self) -> Camera:
        return Camera(self.models, self.params.clone(), self.image_sizes)

    def nan_to_num(self) -> Camera:
        """NaN parameters replaced by a finite stand-in (``fx, fy, cx, cy``: 1, coefficients: 0), for batched maps
        over cameras some of which failed (their results are masked afterwards)."""
        p = self.params
        return self.with_params(torch.cat([p[:, :4].nan_to_num(1.0), p[:, 4:].nan_to_num(0.0)], -1))

    def __repr__(self) -> str:
        return f"Camera({_names(self.models)}, params={tuple(self.params.shape)}, image_sizes={self.image_sizes})"

    # -- the maps -------------------------------------------------------------------------------

    def _groups(self):
        """``(model, index)`` for each model among the cameras (index a long tensor on the parameters' device)."""
        seen: dict = {}
        for i, m in enumerate(self.models):
            seen.setdefault(m, []).append(i)
        return [(m, torch.tensor(ix, device=self.device)) for m, ix in seen.items()]

    def _map(self, name: str, inputs: torch.Tensor, jacobians: bool, out_dim: int, jac_shape=None, **kwargs):
        """Model ``name`` map of ``inputs`` :math:`(C, *, k)`, run once per model (scattered back in camera order)."""
        check_tensor(inputs, f"{name}'s inputs", ["C", "*"], what="(cameras first)", C=len(self))
        params = self.params.to(inputs.dtype) if inputs.is_floating_point() else self.params
        if self.uniform:
            return getattr(self.model, name)(inputs, params, jacobians=jacobians, **kwargs)
        out = inputs.new_zeros(*inputs.shape[:-1], out_dim)
        jac = inputs.new_zeros(*inputs.shape[:-1], *jac_shape) if jacobians else None
        for model, idx in self._groups():
            res = getattr(model, name)(inputs[idx], params[idx, : model.num_params], jacobians=jacobians, **kwargs)
            value, j = (res if jacobians else (res, None))
            out[idx] = value
            if jacobians:
                jac[idx] = j
        return (out, jac) if jacobians else out

    def project(self, points: torch.Tensor, rvec: torch.Tensor | None = None, tvec: torch.Tensor | None = None,
                jacobians: bool = False):
        """Project points :math:`(C, *, 3)`: camera-frame, or world with ``rvec``/``tvec`` :math:`(C, *, 3)`
        (OpenCV's world-to-camera pose, one per point set).

        Returns:
            pixels :math:`(C, *, 2)`; with ``jacobians`` also ``d pixel / d params`` :math:`(C, *, 2, P)` (zero
            beyond a camera's own parameters) and ``d pixel / d point`` :math:`(C, *, 2, 3)` (camera frame).
        """
        check_shape(points, ["*", "3"], "points must be (C, *, 3)")
        if rvec is not None:
            if tvec is None:
                raise ValueError("rvec given without tvec.")
            points = transform_points_rt(points, rvec, tvec)
        check_tensor(points, "project's points", ["C", "*"], what="(cameras first)", C=len(self))
        params = self.params.to(points.dtype)
        if self.uniform:
            uv, J, Jx = self.model.project(points, params, jacobians)
            return (uv, J, Jx) if jacobians else uv
        uv = points.new_zeros(*points.shape[:-1], 2)
        J = points.new_zeros(*points.shape[:-1], 2, params.shape[-1]) if jacobians else None
        Jx = points.new_zeros(*points.shape[:-1], 2, 3) if jacobians else None
        for model, idx in self._groups():
            u, j, jx = model.project(points[idx], params[idx, : model.num_params], jacobians)
            uv[idx] = u
            if jacobians:
                J[idx, ..., : model.num_params], Jx[idx] = j, jx
        return (uv, J, Jx) if jacobians else uv

    def visible(self, points: torch.Tensor) -> torch.Tensor:
        """Which camera-frame points :math:`(C, *, 3)` each camera images, :math:`(C, *)` bool (a pinhole camera: those
        in front of it; a fisheye: every direction)."""
        if self.uniform:
            return self.model.visible(points)
        out = torch.zeros(points.shape[:-1], dtype=torch.bool, device=points.device)
        for model, idx in self._groups():
            out[idx] = model.visible(points[idx])
        return out

    def distort(self, normalized: torch.Tensor, P: torch.Tensor | None = None, jacobians: bool = False):
        """Normalized points :math:`(C, *, 2)` on the ``z = 1`` plane, or pixels of the pinhole camera ``P``
        :math:`(C, 3, 3)` (zero skew; ``P = K``: the ideal pixels), to pixels :math:`(C, *, 2)` (with ``jacobians``
        also ``d pixel / d input`` :math:`(C, *, 2, 2)`); the inverse of :meth:`undistort`. For a fisheye,
        ``(x, y) = tan(theta) (cos(phi), sin(phi))``."""
        if P is not None:
            P = P.to(normalized.dtype).reshape(P.shape[0], *([1] * (normalized.dim() - 2)), 3, 3)
            y = (normalized[..., 1] - P[..., 1, 2]) / P[..., 1, 1]
            x = (normalized[..., 0] - P[..., 0, 2] - P[..., 0, 1] * y) / P[..., 0, 0]
            res = self._map("distort", torch.stack([x, y], -1), jacobians, 2, (2, 2))
            if not jacobians:
                return res
            return res[0], res[1] @ torch.linalg.inv(P[..., :2, :2])
        return self._map("distort", normalized, jacobians, 2, (2, 2))

    def straight(self) -> torch.Tensor:
        """:math:`(C,)` bool: the camera images straight lines straight (a pinhole, or OpenCV's model with every
        coefficient zero): it has no lens distortion to remove."""
        out = torch.zeros(len(self), dtype=torch.bool, device=self.device)
        for model, idx in self._groups():
            out[idx] = model.straight(self.params[idx, : model.num_params])
        return out

    def undistort(self, pixels: torch.Tensor, P: torch.Tensor | None = None, jacobians: bool = False):
        """Pixels :math:`(C, *, 2)` to normalized points :math:`(C, *, 2)` (``cv2.undistortPoints``), or to pixels of
        the pinhole camera ``P`` :math:`(C, 3, 3)` (``P = K``: the ideal pixels); with ``jacobians`` also
        ``d out / d pixel`` :math:`(C, *, 2, 2)`. A fisheye's points are meaningful below 90 degrees
        (:meth:`unproject` reaches beyond)."""
        res = self._map("undistort", pixels, jacobians, 2, (2, 2))
        xy, J = res if jacobians else (res, None)
        if P is not None:
            P = P.to(xy.dtype).reshape(P.shape[0], *([1] * (xy.dim() - 2)), 3, 3)
            xy = torch.stack([P[..., 0, 0] * xy[..., 0] + P[..., 0, 1] * xy[..., 1] + P[..., 0, 2],
                              P[..., 1, 1] * xy[..., 1] + P[..., 1, 2]], -1)
            if jacobians:
                J = P[..., :2, :2] @ J
        return (xy, J) if jacobians else xy

    def unproject(self, pixels: torch.Tensor, jacobians: bool = False):
        """Pixels :math:`(C, *, 2)` to unit viewing rays :math:`(C, *, 3)` (a fisheye's beyond 90 degrees too); with
        ``jacobians`` also ``d ray / d pixel`` :math:`(C, *, 3, 2)`."""
        return self._map("unproject", pixels, jacobians, 3, (3, 2))


def _names(models) -> str:
    return ", ".join(dict.fromkeys(str(m) for m in models))
