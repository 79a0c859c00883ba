"""``cv2.fisheye.estimateNewCameraMatrixForUndistortRectify`` for a fisheye camera, kept for comparison.

It undistorts the midpoints of the image borders, which on a lens seeing 90 degrees or more at its borders gives an
off-centre, sheared or degenerate view; the package frames its views with
:func:`~ccs_kornia.modules.undistort.view_camera.view_camera_matrix` instead (``docs/undistortion.md``).
"""

from __future__ import annotations

import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.modules.undistort.valid_field import check_camera

__all__ = ["fisheye_new_camera_matrix"]


def fisheye_new_camera_matrix(
    camera: Camera, image_size: tuple[int, int], balance: float = 0.0, fov_scale: float = 1.0
) -> torch.Tensor:
    r"""The pinhole camera of the undistorted image, as ``cv2.fisheye.estimateNewCameraMatrixForUndistortRectify``.

    The midpoints of the image borders are undistorted; ``balance = 0`` keeps only the part of the field every
    border midpoint sees (no black areas along the edges' middles), ``balance = 1`` the whole span between them,
    values between interpolate the focal length; ``fov_scale > 1`` zooms out.

    Args:
        camera: ``B`` fisheye cameras (``cv2.fisheye``'s model).
        image_size: ``(W, H)`` of the fisheye images (and of the output).
        balance: in ``[0, 1]``.
        fov_scale: divides the new focal length.

    Returns:
        :math:`(B, 3, 3)` float64 new camera matrix.

    Example:
        >>> from ccs_kornia.geometry.models import FISHEYE
        >>> K = torch.tensor([[300.0, 0, 319.5], [0, 300, 239.5], [0, 0, 1]], dtype=torch.float64)
        >>> P = fisheye_new_camera_matrix(Camera.from_opencv(FISHEYE, K), (640, 480))
        >>> [round(P[0, i, j].item(), 2) for i, j in ((0, 0), (1, 1), (0, 2), (1, 2))]  # as cv2 (D = 0 is no pinhole)
        [233.16, 233.16, 318.92, 239.27]
    """
    check_camera(camera)
    if not all(m.is_fisheye for m in camera.models):
        raise ValueError(f"fisheye_new_camera_matrix is cv2.fisheye's: it takes fisheye cameras, got {camera!r}.")
    if not 0.0 <= balance <= 1.0:
        raise ValueError(f"balance must be in [0, 1], got {balance}.")
    if not fov_scale > 0:
        raise ValueError(f"fov_scale must be positive, got {fov_scale}.")
    w, h = float(image_size[0]), float(image_size[1])
    camera = camera.to(dtype=torch.float64)
    K = camera.K
    mids = torch.tensor([[w / 2, 0], [w, h / 2], [w / 2, h], [0, h / 2]], dtype=torch.float64, device=K.device)
    # normalized coordinates of the border midpoints (cv2 undistorts them with an identity new matrix)
    pts = camera.undistort(mids.expand(K.shape[0], 4, 2))
    aspect = K[:, 0, 0] / K[:, 1, 1]
    pts = torch.stack([pts[..., 0], pts[..., 1] * aspect[:, None]], -1)
    centre = pts.mean(-2)
    lo, hi = pts.amin(-2), pts.amax(-2)
    # cv2's four focal lengths that put each border midpoint on its border; balance 0 takes the largest
    fs = torch.stack([w / 2 / (centre[:, 0] - lo[:, 0]), w / 2 / (hi[:, 0] - centre[:, 0]),
                      h / 2 * aspect / (centre[:, 1] - lo[:, 1]), h / 2 * aspect / (hi[:, 1] - centre[:, 1])], -1)
    f = (balance * fs.amin(-1) + (1 - balance) * fs.amax(-1)) / fov_scale
    new = torch.zeros_like(K)
    new[:, 0, 0], new[:, 1, 1] = f, f / aspect
    new[:, 0, 2] = -centre[:, 0] * f + w / 2
    new[:, 1, 2] = (-centre[:, 1] * f + h / 2 * aspect) / aspect
    new[:, 2, 2] = 1.0
    return new
