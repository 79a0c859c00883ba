r"""The pinhole camera of an undistorted image, from the part of the lens's field that is valid and seen.

An undistorted image is a pinhole view along the calibrated camera's optical axis. Its camera matrix is fixed by
the output size and one focal length: the optical axis sits at the output's centre and ``fy' / fx'`` is the
original ``fy / fx`` (no shear, no shift). The focal length is chosen from the *valid visible region* of the
normalized (``z = 1``) plane: the rays whose projection through the camera's model lies inside the image *and* whose
distance from the axis is below ``max_radius`` (the range where the model is monotonic and was calibrated; see
:func:`~ccs_kornia.modules.undistort.valid_field.valid_radius`). Beyond it the model either folds back (several
rays on one pixel: the smear of a fisheye undistorted too wide) or extrapolates where no corner was seen.

* ``balance = 0``: the largest centred view whose every pixel is in the valid visible region (no black border);
* ``balance = 1``: the smallest zoom that shows the whole region (black corners outside it);
* in between: the focal length interpolated linearly (as OpenCV's ``alpha`` and ``balance``);
* ``fov``: an explicit horizontal field of view, clamped to the horizontal extent of the region.

The region is star-shaped about the axis by construction: along each direction it ends at the first radius where
the projection leaves the image (bisection after a coarse scan), so "inside" is monotonic in the focal length and
the border of the output image decides it. Every model is framed by the same code through the camera's own
:meth:`~ccs_kornia.geometry.camera.Camera.distort`.
"""

from __future__ import annotations

import math

import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.modules.undistort.valid_field import check_camera, valid_radius
from ccs_kornia.runtime.checks import check_tensor

__all__ = ["horizontal_fov", "valid_region_radii", "view_camera_matrix"]

_SCAN_STEPS = 64
_BISECTIONS = 24
_BORDER_SAMPLES = 257  # per side of the view, its corners included


def valid_region_radii(
    camera: Camera,
    max_radius: torch.Tensor,
    image_size: tuple[int, int],
    directions: torch.Tensor,
) -> torch.Tensor:
    r"""How far the valid visible region extends along each direction of the normalized plane.

    Args:
        camera: ``B`` cameras (any models): normalized points to source pixels through :meth:`Camera.distort`.
        max_radius: :math:`(B,)` largest valid distance from the axis on the normalized plane.
        image_size: ``(W, H)`` of the source image; pixel centres are integers, so inside is ``[0, W - 1]``.
        directions: :math:`(B, P, 2)` unit vectors (their dtype and device are the computation's).

    Returns:
        :math:`(B, P)` radii: the first exit from the image along each direction, at most ``max_radius``.

    Example:
        >>> from ccs_kornia.geometry.models import PINHOLE
        >>> K = torch.tensor([[100.0, 0, 49.5], [0, 100, 39.5], [0, 0, 1]], dtype=torch.float64)
        >>> dirs = torch.tensor([[[1.0, 0.0], [0.0, 1.0]]], dtype=torch.float64)
        >>> valid_region_radii(Camera.from_opencv(PINHOLE, K), torch.tensor([5.0]), (100, 80), dirs)
        tensor([[0.4950, 0.3950]], dtype=torch.float64)
    """
    check_camera(camera)
    check_tensor(directions, "directions", ["B", "P", "2"], what="(one per camera)", B=len(camera))
    check_tensor(max_radius, "max_radius", [len(camera)], what="(one per camera)")
    b, p, _ = directions.shape
    w, h = float(image_size[0]), float(image_size[1])
    cam = camera.to(device=directions.device, dtype=directions.dtype)

    def inside(radii: torch.Tensor) -> torch.Tensor:  # radii (B, P, S) -> (B, P, S)
        pts = (radii[..., None] * directions[:, :, None, :]).reshape(b, -1, 2)
        uv = cam.distort(pts).reshape(*radii.shape, 2)
        return (uv[..., 0] >= 0) & (uv[..., 0] <= w - 1) & (uv[..., 1] >= 0) & (uv[..., 1] <= h - 1)

    top = max_radius.to(directions)[:, None, None]
    steps = torch.arange(1, _SCAN_STEPS + 1, dtype=directions.dtype, device=directions.device) / _SCAN_STEPS
    radii = top * steps  # (B, 1, S)
    ok = inside(radii.expand(b, p, -1))
    # first sample outside (S where none): the region ends between it and the sample before
    index = torch.arange(_SCAN_STEPS, device=directions.device)
    first_out = torch.where(~ok, index, _SCAN_STEPS).amin(-1)
    lo = top[..., 0] * first_out.to(directions.dtype) / _SCAN_STEPS
    hi = top[..., 0] * (first_out + 1).to(directions.dtype) / _SCAN_STEPS
    open_end = first_out == _SCAN_STEPS
    if not bool(open_end.all()):
        for _ in range(_BISECTIONS):
            mid = 0.5 * (lo + hi)
            good = inside(mid[..., None])[..., 0]
            lo, hi = torch.where(good, mid, lo), torch.where(good, hi, mid)
    return torch.where(open_end, top[..., 0].expand(b, p), lo)


def _border_offsets(w: int, h: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """Points along the border of a ``w x h`` image, as offsets from its centre, :math:`(P, 2)`."""
    cx, cy = (w - 1) / 2, (h - 1) / 2
    xs = torch.linspace(-cx, cx, min(w, _BORDER_SAMPLES), dtype=dtype, device=device)
    ys = torch.linspace(-cy, cy, min(h, _BORDER_SAMPLES), dtype=dtype, device=device)
    return torch.cat([torch.stack([xs, torch.full_like(xs, -cy)], -1), torch.stack([xs, torch.full_like(xs, cy)], -1),
                      torch.stack([torch.full_like(ys, -cx), ys], -1), torch.stack([torch.full_like(ys, cx), ys], -1)])


def view_camera_matrix(
    camera: Camera,
    image_size: tuple[int, int],
    balance: float = 0.0,
    fov: float | None = None,
    max_radius: torch.Tensor | None = None,
    num_directions: int = 360,
) -> torch.Tensor:
    r"""The camera matrix of an undistorted view centred on the optical axis (see the module's description).

    The analogue of ``cv2.getOptimalNewCameraMatrix(..., alpha=balance, centerPrincipalPoint=True)`` for every model
    (``cv2.fisheye``'s included), limited to the lens's valid field: a model that folds over inside the image gives
    no smear.

    Args:
        camera: ``B`` cameras (any models; each one's ``fy / fx`` is kept).
        image_size: ``(W, H)`` of the source images and of the view.
        balance: in ``[0, 1]``: 0 no black border, 1 the whole valid region visible, linear in the focal length.
        fov: horizontal field of view in degrees (overrides ``balance``), clamped to the region's horizontal
            extent (compare :func:`horizontal_fov` of the result to tell).
        max_radius: :math:`(B,)` the valid radius on the normalized plane (default:
            :func:`~ccs_kornia.modules.undistort.valid_field.valid_radius` without points).
        num_directions: directions sampled around the axis for ``balance > 0`` and ``fov``.

    Returns:
        :math:`(B, 3, 3)` float64: ``[[f, 0, (W - 1) / 2], [0, f fy / fx, (H - 1) / 2], [0, 0, 1]]``, the ``new_K``
        of :func:`~ccs_kornia.modules.undistort.undistort_image.undistort_image`.

    Example:
        >>> from ccs_kornia.geometry.models import OPENCV5, PINHOLE
        >>> K = torch.tensor([[100.0, 0, 49.5], [0, 100, 39.5], [0, 0, 1]], dtype=torch.float64)
        >>> P = view_camera_matrix(Camera.from_opencv(PINHOLE, K), (100, 80))  # no distortion: K again
        >>> [round(v, 3) for v in P[0, :2].flatten().tolist()]
        [100.0, 0.0, 49.5, 0.0, 100.0, 39.5]
        >>> K = torch.tensor([[500.0, 0, 319.5], [0, 500, 239.5], [0, 0, 1]], dtype=torch.float64)
        >>> barrel = Camera.from_opencv(OPENCV5, K, torch.tensor([-0.2, 0.05, 0.0, 0.0, 0.0]), (640, 480))
        >>> P0, P1 = view_camera_matrix(barrel, (640, 480)), view_camera_matrix(barrel, (640, 480), balance=1.0)
        >>> round(P0[0, 0, 0].item(), 1), round(P1[0, 0, 0].item(), 1)  # getOptimalNewCameraMatrix: 476.3, 433.1
        (476.3, 433.1)
    """
    check_camera(camera)
    camera = camera.to(dtype=torch.float64)
    if max_radius is None:
        max_radius = valid_radius(camera)
    K = camera.K
    check_tensor(max_radius, "max_radius", K.shape[:1])
    max_radius = max_radius.to(K)
    if not 0.0 <= balance <= 1.0:
        raise ValueError(f"balance must be in [0, 1], got {balance}.")
    if fov is not None and not 0.0 < fov < 180.0:
        raise ValueError(f"fov must be in (0, 180) degrees, got {fov}.")
    w, h = int(image_size[0]), int(image_size[1])
    b, dtype, device = K.shape[0], K.dtype, K.device
    aspect = K[:, 1, 1] / K[:, 0, 0]  # fy / fx, kept by the view
    half_w, half_h = (w - 1) / 2, (h - 1) / 2
    if fov is None:
        # balance 0: every border pixel of the view inside the region; on the normalized plane the border pixel at
        # offset (du, dv) is (du, dv / aspect) / f, so f >= |offset| / radius along its direction
        offsets = _border_offsets(w, h, dtype, device)[None].expand(b, -1, -1)
        plane = torch.stack([offsets[..., 0], offsets[..., 1] / aspect[:, None]], -1)
        length = plane.norm(dim=-1).clamp_min(1e-12)
        radii = valid_region_radii(camera, max_radius, image_size, plane / length[..., None])
        if bool((radii <= 0).any()):
            raise ValueError("no part of the image is in the valid field of the lens model (principal point outside?)")
        focal = (length / radii).amax(-1)
        if balance > 0.0:
            extent_x, extent_y = _region_extent(camera, max_radius, image_size, num_directions, dtype, device)
            whole = torch.minimum(half_w / extent_x, half_h / (aspect * extent_y))  # balance 1: all of it in view
            focal = (1.0 - balance) * focal + balance * torch.minimum(whole, focal)
    else:
        extent_x, _ = _region_extent(camera, max_radius, image_size, num_directions, dtype, device)
        focal = half_w / torch.minimum(torch.full_like(extent_x, math.tan(math.radians(fov / 2))), extent_x)
    new = torch.zeros_like(K)
    new[:, 0, 0], new[:, 1, 1] = focal, focal * aspect
    new[:, 0, 2], new[:, 1, 2], new[:, 2, 2] = half_w, half_h, 1.0
    return new


def _region_extent(camera, max_radius, image_size, num_directions, dtype, device):
    """Largest ``|x|`` and ``|y|`` of the valid visible region, each :math:`(B,)`.

    The region's extreme points are often corners of the image (sharp in direction), so each of the four extremes
    found on the coarse ring of directions is refined on a finer ring around it.
    """
    b = max_radius.shape[0]
    step = 2 * math.pi / num_directions
    angles = (torch.arange(num_directions, dtype=dtype, device=device) * step)[None].expand(b, -1)
    fine = torch.linspace(-step, step, 65, dtype=dtype, device=device)

    def points(phi: torch.Tensor) -> torch.Tensor:
        dirs = torch.stack([phi.cos(), phi.sin()], -1)
        return valid_region_radii(camera, max_radius, image_size, dirs)[..., None] * dirs

    coarse = points(angles)
    signs = ((0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0))  # +x, -x, +y, -y
    best = torch.stack([(sign * coarse[..., axis]).argmax(-1) for axis, sign in signs], -1)  # (B, 4)
    around = angles.gather(1, best)[..., None] + fine  # (B, 4, 65): one call for the four refinements
    refined = points(around.reshape(b, -1)).reshape(b, 4, -1, 2)
    ext = [(sign * refined[:, k, :, axis]).amax(-1).clamp_min(0.0) for k, (axis, sign) in enumerate(signs)]
    return torch.maximum(ext[0], ext[1]), torch.maximum(ext[2], ext[3])


def horizontal_fov(K: torch.Tensor, image_size: tuple[int, int]) -> torch.Tensor:
    r"""The horizontal field of view, in degrees, of a view made by :func:`view_camera_matrix`.

    Args:
        K: :math:`(B, 3, 3)` the view's camera (optical axis at the image centre).
        image_size: ``(W, H)``.

    Returns:
        :math:`(B,)` ``2 atan((W - 1) / 2 / fx)`` in degrees.

    Example:
        >>> horizontal_fov(torch.tensor([[[50.0, 0, 49.5], [0, 50, 39.5], [0, 0, 1]]]), (101, 80))
        tensor([90.])
    """
    return torch.rad2deg(2 * torch.atan((image_size[0] - 1) / 2 / K[:, 0, 0]))
