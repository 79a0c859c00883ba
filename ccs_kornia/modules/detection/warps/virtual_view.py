"""Second look at missed views with the calibrated lens: detection on virtual pinhole views, corners mapped back.

Once a camera is calibrated from the boards that were found, its lens is known. A board the detector missed
on the original image — strongly curved near a fisheye's rim, or crossing the image where the distortion is
largest — is looked for again on *virtual pinhole views*: the image resampled as a distortion-free camera
looking in a given direction (:func:`view_directions`: the optical axis, and for wide lenses rings of directions
tilted away from it). There the board's rows are straight again, as the detector was trained to see them.
Corners found in a virtual view are mapped back exactly (pixel -> ray -> the calibrated projection) and refined
on the original image at full resolution, so they are measurements of the original image like any other.

This is the paper's idea of correcting before detecting, with the calibration's own lens model instead of the
network's estimate: the network's radial model cannot describe a fisheye (it straightens a real fisheye set's rows by
3 %, ``docs/measurements.md``), the calibrated Kannala-Brandt model does.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterable, Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass

import torch
from kornia.geometry.grid import create_meshgrid
from kornia.geometry.transform import remap

from ccs_kornia.geometry.camera import Camera, axis_angle_to_rotation_matrix
from ccs_kornia.modules.detection.base import DetectionResult
from ccs_kornia.modules.detection.warps.warped_detection import Warp, map_back
from ccs_kornia.runtime.checks import check_board_size, check_shape

__all__ = ["VIEWS_PER_ROUND", "VirtualView", "view_directions", "virtual_view_rays", "detect_with_calibrated_lens"]


def view_directions(wide: bool, fov_deg: float = 110.0) -> list[tuple[float, float, float]]:
    """The virtual views, in the order they are tried: ``(yaw, pitch, field of view)`` in degrees.

    The axis; for a wide lens also a ring of six directions 55 degrees off it, the same six directions 35 degrees
    off it, and the 55-degree ring again with a 130-degree view (a board near a fisheye's rim can be too large for
    110 degrees). On a real fisheye set each ring finds boards the others miss (``docs/measurements.md``).

    Example:
        >>> len(view_directions(False)), len(view_directions(True))
        (1, 19)
    """
    out = [(0.0, 0.0, fov_deg)]
    if wide:
        for tilt, offset, fov in ((55.0, 0.0, fov_deg), (35.0, 0.0, fov_deg), (55.0, 0.0, 130.0)):
            out += [(tilt * math.cos(math.radians(60 * k + offset)), tilt * math.sin(math.radians(60 * k + offset)), fov)
                    for k in range(6)]
    return out


def virtual_view_rays(direction: tuple[float, float], fov_deg: float, side: int, dtype=torch.float64,
                      device=None) -> tuple[torch.Tensor, float, torch.Tensor]:
    r"""Camera-frame rays :math:`(side * side, 3)` of a square virtual pinhole view, its focal length (px) and its
    rotation :math:`(3, 3)` (virtual-view ray -> camera-frame ray: ``ray @ R.T``).

    Args:
        direction: (yaw, pitch) in degrees: where the virtual camera looks.
        fov_deg: its full field of view across.
        side: its size in pixels.
    """
    f, R = _view_frame(direction, fov_deg, side, dtype, device)
    grid = create_meshgrid(side, side, normalized_coordinates=False, device=device, dtype=dtype).reshape(-1, 2)
    c = (side - 1) / 2
    rays = torch.stack([(grid[:, 0] - c) / f, (grid[:, 1] - c) / f, torch.ones_like(grid[:, 0])], -1)
    return rays @ R.T, f, R


def _view_frame(direction: tuple[float, float], fov_deg: float, side: int, dtype=torch.float64,
                device=None) -> tuple[float, torch.Tensor]:
    """The focal length (px) and rotation :math:`(3, 3)` of :func:`virtual_view_rays`' view."""
    yaw, pitch = direction
    R = axis_angle_to_rotation_matrix(torch.tensor([[math.radians(-pitch), math.radians(yaw), 0.0]], dtype=dtype,
                                                   device=device))[0]
    return (side / 2) / math.tan(math.radians(fov_deg / 2)), R


def _project(rays: torch.Tensor, camera: Camera) -> torch.Tensor:
    """Pixels (B, P, 2) of rays (B, P, 3) under each camera; NaN where the camera cannot see the ray."""
    uv = camera.project(rays)
    return torch.where(camera.visible(rays)[..., None], uv, torch.full_like(uv, float("nan")))


def _wide(camera: Camera) -> bool:
    """The rings of tilted views too: a fisheye lens (boards near its rim are curved far beyond the axis view)."""
    return any(m.is_fisheye for m in camera.models)


#: virtual views looked at per round (:func:`detect_with_calibrated_lens`): each view of a round is looked at on the
#: images without a board before the round, so a round's views can run at once (``view_pool``: one per worker process
#: on 2 cores) and give the same boards whatever runs them; a board found on the first view of a round costs its
#: second view's work on that image
VIEWS_PER_ROUND = 2


@contextmanager
def _in_order(fn: Callable) -> Iterator[Callable[[Iterable], Iterator]]:
    yield lambda items: (fn(item) for item in items)


@dataclass(frozen=True)
class VirtualView(Warp):
    """The virtual pinhole view ``direction`` ``(yaw, pitch, fov)`` (degrees), ``side`` px square, of images under
    their calibrated cameras (``B``, float64) of ``size`` ``(W, H)``; pixels map back through rays and the calibrated
    projection.

    Example:
        >>> from ccs_kornia.geometry.models import FISHEYE
        >>> cam = Camera(FISHEYE, torch.tensor([200.0, 200, 160, 120, 0, 0, 0, 0], dtype=torch.float64))
        >>> warp = VirtualView((0.0, 0.0, 110.0), 96, cam, (320, 240))
        >>> warp.apply(torch.rand(1, 1, 240, 320)).shape, warp.back(torch.tensor([[[47.5, 47.5]]]))[0].tolist()
        (torch.Size([1, 1, 96, 96]), [[[160.0, 120.0]]])
    """

    direction: tuple[float, float, float]
    side: int
    camera: Camera
    size: tuple[int, int]

    def apply(self, images: torch.Tensor) -> torch.Tensor:
        yaw, pitch, fov = self.direction
        b = images.shape[0]
        rays = virtual_view_rays((yaw, pitch), fov, self.side, device=images.device)[0]
        src = _project(rays.expand(b, -1, -1), self.camera)
        src = src.reshape(b, self.side, self.side, 2).float()
        # rays the camera cannot see land outside the image: zeros there, as the border of any undistortion
        src = torch.nan_to_num(src, nan=-10.0)
        view = remap(images.float(), src[..., 0], src[..., 1], mode="bilinear", align_corners=True)
        return view.clamp(0, 1)

    def back(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        # virtual-view pixels -> rays -> the calibrated projection in the original image
        yaw, pitch, fov = self.direction
        pix = points.to(self.camera.device, torch.float64)
        f, R = _view_frame((yaw, pitch), fov, self.side, device=self.camera.device)
        c = (self.side - 1) / 2
        local = torch.stack([(pix[..., 0] - c) / f, (pix[..., 1] - c) / f, torch.ones_like(pix[..., 0])], -1)
        back = _project(local @ R.T, self.camera)
        w, h = self.size
        inside = back.isfinite().all(-1).all(-1) & (back >= 0).all(-1).all(-1)
        inside = inside & (back[..., 0] <= w - 1).all(-1) & (back[..., 1] <= h - 1).all(-1)
        return back, inside


def _look_at_view(detect: Callable, images: torch.Tensor, camera: Camera, board_size: tuple[int, int], side: int,
                  item: tuple) -> DetectionResult:
    """The detection on virtual view ``item = ((yaw, pitch, fov), todo)`` of the images ``todo`` (virtual-view
    pixels)."""
    direction, todo = item
    h, w = images.shape[-2:]
    warp = VirtualView(direction, side, camera[todo], (int(w), int(h)))
    return detect(warp.apply(images[todo]), board_size)


def detect_with_calibrated_lens(
    detect: Callable[[torch.Tensor, tuple[int, int]], DetectionResult],
    refine: Callable[[torch.Tensor, torch.Tensor, tuple[int, int]], torch.Tensor],
    images: torch.Tensor,
    camera: Camera,
    board_size: tuple[int, int],
    fov_deg: float = 110.0,
    side: int = 480,
    view_pool: Callable[[Callable], AbstractContextManager] | None = None,
) -> DetectionResult:
    r"""Look for the board on virtual pinhole views of each image under its calibrated camera.

    The views (:func:`view_directions`) are looked at in rounds of :data:`VIEWS_PER_ROUND`, each on the images
    still without a board; an image takes its board from the first view, in order, that finds it.

    Args:
        detect: a detector ``(images (B,1,h,w), board) -> DetectionResult``.
        refine: full-resolution refinement ``(images, corners (B,N,2), board) -> corners``.
        images: :math:`(B, 1, H, W)` in ``[0, 1]`` (the original images of missed views).
        camera: each image's calibrated camera (``B``; for a fisheye the rings of tilted views are looked at too).
        board_size: ``(cols, rows)``.
        fov_deg, side: field of view of the axis view (and the first rings), size of each virtual view.
        view_pool: ``view_pool(fn)``, a context manager giving ``run(items)`` that yields ``fn(item)`` for each item
            in order, e.g. ``functools.partial(workers.worker_pool, workers=2)`` to look at a round's views
            in forked processes (``fn`` is made before the block and inherited by them); default: here, in order.
            The boards are the same either way.

    Returns:
        :class:`DetectionResult` in the original images' pixels; ``reasons`` say which view found the board.

    Example:
        >>> from ccs_kornia.modules.detection.factory import make_detector
        >>> det = make_detector("opencv")
        >>> from ccs_kornia.geometry.models import FISHEYE
        >>> cam = Camera(FISHEYE, torch.tensor([200.0, 200, 160, 120, 0, 0, 0, 0], dtype=torch.float64))
        >>> out = detect_with_calibrated_lens(det, lambda i, c, b: c, torch.rand(1, 1, 240, 320), cam, (6, 4), side=160)
        >>> bool(out.found[0]), out.corners.shape
        (False, torch.Size([1, 24, 2]))
    """
    check_shape(images, [len(camera), "C", "H", "W"],
                f"images must be (B, 1, H, W) with B={len(camera)} (one per camera)")
    b, _, h, w = images.shape
    cols, rows = check_board_size(board_size, min_side=1)
    n = cols * rows
    device = images.device
    out = DetectionResult(torch.zeros(b, n, 2, dtype=torch.float32, device=device),
                          torch.zeros(b, dtype=torch.bool, device=device),
                          ["board not found on the virtual pinhole views of the calibrated lens"] * b)
    camera = camera.to(device, torch.float64)
    views = list(enumerate(view_directions(_wide(camera), fov_deg)))
    look = functools.partial(_look_at_view, detect, images, camera, board_size, side)
    with (view_pool or _in_order)(look) as run:
        for start in range(0, len(views), VIEWS_PER_ROUND):
            todo = (~out.found).nonzero().flatten()
            if todo.numel() == 0:
                break
            batch = views[start:start + VIEWS_PER_ROUND]
            for (k, (yaw, pitch, fov)), got in zip(batch, run([(direction, todo) for _, direction in batch])):
                # an image whose board an earlier view of the round found keeps that one
                got.found = got.found.to(device) & ~out.found[todo]
                if not bool(got.found.any()):
                    continue
                warp = VirtualView((yaw, pitch, fov), side, camera[todo], (int(w), int(h)))
                mapped = map_back(warp, got, refine, images[todo], board_size)
                mapped.reasons = [f"found on virtual pinhole view {k} of the calibrated lens (direction {yaw:.0f}, "
                                  f"{pitch:.0f} deg, {fov:.0f} deg wide)"] * todo.numel()
                out.fill(todo, mapped)
    return out
