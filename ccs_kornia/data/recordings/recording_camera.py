"""A camera that records video: intrinsics and lens, where it sits in a rig, and when each of its rows is exposed.

The lens is a type (:class:`PinholeLens`, :class:`OpenCVLens`, :class:`FisheyeLens`) with its camera model
(:attr:`Lens.model`): the camera projects camera-frame points (the ground truth: :attr:`RecordingCamera.camera`, valid
where :func:`~ccs_kornia.data.render.lens.project_board` says so) and the lens gives the ray of every pixel centre with
its derivatives along the image axes (rendering: the renderer's exact inverses, computed once per camera and cached).

Timing of frame ``k`` (seconds): it starts at ``start + k / fps``; row ``y`` is exposed from
``frame_start + y * line_time`` for ``exposure`` seconds (a rolling shutter reads one row every ``line_time``; a
global shutter has ``line_time = 0``). The frame's time is the middle of the exposure of its middle row,
``frame_start + (readout + exposure) / 2`` with ``readout = (H - 1) * line_time``: the instant its ground-truth pose
refers to. What a recording program would log as the frame's timestamp is that time plus a constant ``latency`` and
a random ``jitter`` (standard deviation, per frame): the software clock a rig's frames are paired by.

Rig: ``x_cam = R x_rig + T`` (the rig's frame is camera 0's in :func:`~ccs_kornia.data.recordings.recordings.webcam_rig`).

Example:
    >>> import torch
    >>> K = torch.tensor([[600.0, 0, 319.5], [0, 600, 239.5], [0, 0, 1]])
    >>> cam = RecordingCamera(K, (640, 480), OpenCVLens([-0.1, 0.02, 0, 0, 0]), line_time=30e-6)
    >>> round(cam.readout * 1e3, 2), cam.num_frames(1.0)
    (14.37, 30)
    >>> pix, ok = cam.project(torch.tensor([[[0.0, 0.0, 1.0]]], dtype=torch.float64))
    >>> pix.tolist(), ok.tolist()
    ([[[319.5, 239.5]]], [[True]])
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import torch
from torch import Tensor

from ccs_kornia.data.render.fisheye import kb_fold, kb_unproject
from ccs_kornia.data.render.lens import (
    opencv_fold_radius,
    opencv_inverse_grid,
    pixels_to_normalized,
    undistort_opencv_pixels,
)
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.factory import FISHEYE, OPENCV5, PINHOLE

__all__ = ["FisheyeLens", "Lens", "OpenCVLens", "PinholeLens", "PixelRays", "RecordingCamera", "lens_from_json"]


@dataclass
class PixelRays:
    """The ray ``(x, y, z)`` each pixel centre sees and its derivatives per pixel along the image's x and y axes.

    Fields are :math:`(H, W)` float32 tensors, or 0-dim tensors where they do not vary over the image (a pinhole's
    ``z = 1`` and its constant derivatives); ``reach`` :math:`(H, W)` bool: the pixel has a ray (inside the lens'
    image circle and before its distortion folds over).
    """

    x: Tensor
    y: Tensor
    z: Tensor
    x_px: Tensor
    x_py: Tensor
    y_px: Tensor
    y_py: Tensor
    z_px: Tensor
    z_py: Tensor
    reach: Tensor

    def crop(self, y0: int, y1: int, x0: int, x1: int) -> PixelRays:
        """The rays of the pixels in rows ``y0:y1`` and columns ``x0:x1``."""
        def cut(t: Tensor) -> Tensor:
            return t[y0:y1, x0:x1] if t.dim() == 2 else t

        return PixelRays(*(cut(getattr(self, f)) for f in self.__dataclass_fields__))


def _pixel_grid(image_size: tuple[int, int], dtype=torch.float64) -> tuple[Tensor, Tensor]:
    w, h = image_size
    ys, xs = torch.meshgrid(torch.arange(h, dtype=dtype), torch.arange(w, dtype=dtype), indexing="ij")
    return xs, ys


def _grid_derivatives(f: Tensor) -> tuple[Tensor, Tensor]:
    """``df/dx, df/dy`` per pixel (central differences, one-sided at the image border)."""
    dy, dx = torch.gradient(f, dim=(0, 1))
    return dx, dy


class Lens:
    """A camera's lens: its camera model (:attr:`model`, :meth:`camera`: where camera-frame points land,
    :meth:`project`) and which ray each pixel sees (:meth:`rays`, :meth:`unproject`)."""

    #: the lens' camera model
    model: CameraModel = PINHOLE

    @property
    def coeffs(self) -> Tensor | None:
        """The model's coefficients in OpenCV's layout (``None``: a pinhole's)."""
        return None

    def camera(self, K: Tensor, image_size: tuple[int, int] | None = None) -> Camera:
        """The camera of this lens behind ``K`` :math:`(3, 3)` (zero skew), float64."""
        return Camera.from_opencv(self.model, K.to(torch.float64), self.coeffs, image_size)

    def project(self, points: Tensor, camera: Camera) -> tuple[Tensor, Tensor]:
        """Camera-frame points :math:`(..., 3)` to pixels :math:`(..., 2)` through ``camera`` (this lens'
        :meth:`camera`) and ``ok`` :math:`(...)` (in front of the camera and where the lens images them without
        folding over: the points :func:`~ccs_kornia.data.render.lens.project_board` accepts), float64."""
        pts = points.to(torch.float64)
        z = pts[..., 2]
        ok = z > 1e-9
        safe = torch.cat([pts[..., :2], torch.where(ok, z, torch.ones_like(z)).unsqueeze(-1)], -1)
        if self.coeffs is not None:
            ok = ok & ((safe[..., :2] / safe[..., 2:]).norm(dim=-1) < self._fold)
        return camera.to(pts.device).project(safe[None])[0], ok

    def rays(self, K: Tensor, image_size: tuple[int, int]) -> PixelRays:
        """The rays of every pixel centre of an image of ``image_size`` ``(W, H)``."""
        raise NotImplementedError

    def unproject(self, pixels: Tensor, K: Tensor) -> Tensor:
        """Pixels :math:`(P, 2)` to rays :math:`(P, 3)` (``z = 1`` for pinhole lenses), float64."""
        raise NotImplementedError

    def to_json(self) -> dict:
        """The lens as JSON (:func:`lens_from_json` reads it back)."""
        raise NotImplementedError


class PinholeLens(Lens):
    """An ideal pinhole: straight lines stay straight."""

    def rays(self, K: Tensor, image_size: tuple[int, int]) -> PixelRays:
        K = K.to(torch.float64)
        xs, ys = _pixel_grid(image_size)
        x, y = pixels_to_normalized(xs[None], ys[None], K[None])
        fx, fy, skew = float(K[0, 0]), float(K[1, 1]), float(K[0, 1])
        c = lambda v: torch.tensor(v, dtype=torch.float32)
        return PixelRays(x[0].float(), y[0].float(), c(1.0), c(1.0 / fx), c(-skew / (fx * fy)), c(0.0), c(1.0 / fy),
                         c(0.0), c(0.0), torch.ones(image_size[1], image_size[0], dtype=torch.bool))

    def unproject(self, pixels: Tensor, K: Tensor) -> Tensor:
        K = K.to(torch.float64)
        x, y = pixels_to_normalized(pixels[None, :, 0].double(), pixels[None, :, 1].double(), K[None])
        return torch.stack([x[0], y[0], torch.ones_like(x[0])], -1)

    def to_json(self) -> dict:
        return {"kind": "pinhole"}


class OpenCVLens(Lens):
    """OpenCV's distortion ``(k1, k2, p1, p2, k3)`` (``cv2.projectPoints``); pixels beyond the radius where the model
    folds over have no ray (rendered black).

    Args:
        dist: five coefficients.
    """

    model = OPENCV5

    def __init__(self, dist) -> None:
        d = torch.as_tensor(dist, dtype=torch.float64).flatten()
        if d.numel() != 5:
            raise ValueError(f"OpenCVLens takes (k1, k2, p1, p2, k3), got {d.numel()} coefficients.")
        self.dist = d
        self._fold = float(opencv_fold_radius(d[None])[0][0])  # normalised radius where the model folds over (inf: never)

    @property
    def coeffs(self) -> Tensor:
        """``k1, k2, p1, p2, k3``."""
        return self.dist

    def rays(self, K: Tensor, image_size: tuple[int, int]) -> PixelRays:
        K = K.to(torch.float64)[None]
        xs, ys = _pixel_grid(image_size)
        xt, yt = pixels_to_normalized(xs[None], ys[None], K)
        x, y, ok = opencv_inverse_grid(xt, yt, K, self.dist[None], image_size)
        x, y, ok = x[0], y[0], ok[0]
        x_px, x_py = _grid_derivatives(x)
        y_px, y_py = _grid_derivatives(y)
        zero = torch.tensor(0.0)
        return PixelRays(x.float(), y.float(), torch.tensor(1.0), x_px.float(), x_py.float(), y_px.float(),
                         y_py.float(), zero, zero, ok)

    def unproject(self, pixels: Tensor, K: Tensor) -> Tensor:
        K = K.to(torch.float64)[None]
        ideal, _ = undistort_opencv_pixels(pixels.double()[None], K, self.dist[None])
        x, y = pixels_to_normalized(ideal[..., 0], ideal[..., 1], K)
        return torch.stack([x[0], y[0], torch.ones_like(x[0])], -1)

    def to_json(self) -> dict:
        return {"kind": "opencv", "dist": self.dist.tolist()}


class FisheyeLens(Lens):
    """The Kannala-Brandt lens of ``cv2.fisheye`` (``k1..k4``) with an image circle of ``fov_deg`` degrees (pixels
    beyond it are black).

    Args:
        k: four coefficients.
        fov_deg: the field of view of the image circle.
    """

    model = FISHEYE

    def __init__(self, k, fov_deg: float = 180.0) -> None:
        kk = torch.as_tensor(k, dtype=torch.float64).flatten()
        if kk.numel() != 4:
            raise ValueError(f"FisheyeLens takes (k1, k2, k3, k4), got {kk.numel()} coefficients.")
        if not 0.0 < float(fov_deg) <= 360.0:
            raise ValueError(f"fov_deg must be in (0, 360], got {fov_deg}.")
        self.k, self.fov_deg = kk, float(fov_deg)
        #: the largest angle from the axis the lens images: its image circle, or where the model folds over
        self.theta_max = min(math.radians(self.fov_deg) / 2, float(kb_fold(kk[None])[0]))

    @property
    def coeffs(self) -> Tensor:
        """``k1 .. k4``."""
        return self.k

    def project(self, points: Tensor, camera: Camera) -> tuple[Tensor, Tensor]:
        """Camera-frame points :math:`(..., 3)` to pixels through ``camera`` (every direction) and ``ok``: inside the
        image circle and before the model folds over."""
        pts = points.to(torch.float64)
        x, y, z = pts.unbind(-1)
        rho = (x * x + y * y).sqrt()
        ok = (torch.atan2(rho, z) < self.theta_max) & (rho + z.abs() > 0)
        return camera.to(pts.device).project(pts[None])[0], ok

    def _fisheye_row(self, b: int, device) -> Tensor | None:
        row = torch.cat([self.k, torch.tensor([math.radians(self.fov_deg) / 2], dtype=torch.float64)])
        return row.to(device).expand(b, 5)

    def rays(self, K: Tensor, image_size: tuple[int, int]) -> PixelRays:
        K = K.to(torch.float64)[None]
        xs, ys = _pixel_grid(image_size)
        xd, yd = pixels_to_normalized(xs[None], ys[None], K)
        x, y, z, reach = kb_unproject(xd, yd, self._fisheye_row(1, "cpu"))
        x, y, z, reach = x[0], y[0], z[0], reach[0]
        derivs = [d.float() for f in (x, y, z) for d in _grid_derivatives(f)]
        return PixelRays(x.float(), y.float(), z.float(), *derivs, reach)

    def unproject(self, pixels: Tensor, K: Tensor) -> Tensor:
        K = K.to(torch.float64)[None]
        xd, yd = pixels_to_normalized(pixels[None, :, 0].double(), pixels[None, :, 1].double(), K)
        x, y, z, _ = kb_unproject(xd, yd, self._fisheye_row(1, "cpu"))
        return torch.stack([x[0], y[0], z[0]], -1)

    def to_json(self) -> dict:
        return {"kind": "fisheye", "k": self.k.tolist(), "fov_deg": self.fov_deg}


def lens_from_json(data: dict) -> Lens:
    """The lens written by :meth:`Lens.to_json`.

    Example:
        >>> lens_from_json(OpenCVLens([-0.2, 0.05, 0, 0, 0]).to_json()).dist.tolist()
        [-0.2, 0.05, 0.0, 0.0, 0.0]
    """
    readers = {
        "pinhole": lambda d: PinholeLens(),
        "opencv": lambda d: OpenCVLens(d["dist"]),
        "fisheye": lambda d: FisheyeLens(d["k"], d["fov_deg"]),
    }
    kind = data.get("kind")
    if kind not in readers:
        raise ValueError(f"unknown lens {kind!r}; expected pinhole, opencv or fisheye")
    return readers[kind](data)


@dataclass(eq=False)
class RecordingCamera:
    """A video camera: intrinsics, lens, sensor timing, clock and pose in the rig.

    Args:
        K: :math:`(3, 3)` camera matrix.
        image_size: ``(W, H)``.
        lens: a :class:`Lens` (default a pinhole).
        fps: frames per second.
        exposure: exposure time of a row, seconds (motion blur integrates the board over it).
        line_time: seconds between the exposures of consecutive rows (``0``: a global shutter).
        start: start of the first frame's exposure, seconds.
        latency, jitter: the logged timestamp is the frame's time plus ``latency`` plus a Gaussian of standard
            deviation ``jitter`` (seconds).
        noise: standard deviation of the sensor's read noise (grey levels in ``[0, 1]``); shot noise of the same
            size at full white is added with it.
        gamma: the tone curve ``I ** (1 / gamma)`` applied before quantisation (``1``: linear).
        R, T: pose in the rig, ``x_cam = R x_rig + T`` (default identity, zero).
    """

    K: Tensor
    image_size: tuple[int, int]
    lens: Lens = field(default_factory=PinholeLens)
    fps: float = 30.0
    exposure: float = 0.008
    line_time: float = 0.0
    start: float = 0.0
    latency: float = 0.0
    jitter: float = 0.0
    noise: float = 0.01
    gamma: float = 1.0
    R: Tensor | None = None
    T: Tensor | None = None

    def __post_init__(self) -> None:
        self.K = torch.as_tensor(self.K, dtype=torch.float64)
        if self.K.shape != (3, 3):
            raise ValueError(f"K must be (3, 3), got {tuple(self.K.shape)}.")
        if len(self.image_size) != 2 or min(int(v) for v in self.image_size) < 2:
            raise ValueError(f"image_size must be (W, H) with both >= 2, got {self.image_size}.")
        self.image_size = (int(self.image_size[0]), int(self.image_size[1]))
        if not isinstance(self.lens, Lens):
            raise TypeError(f"lens must be a Lens, got {type(self.lens).__name__}.")
        if not self.fps > 0 or self.exposure < 0 or self.line_time < 0 or self.jitter < 0 or self.noise < 0:
            raise ValueError("fps must be positive; exposure, line_time, jitter and noise not negative.")
        if self.readout >= 1.0 / self.fps:
            raise ValueError(f"the rolling shutter's readout ({self.readout * 1e3:.1f} ms) must be shorter than a frame "
                             f"({1e3 / self.fps:.1f} ms).")
        if not self.gamma > 0:
            raise ValueError(f"gamma must be positive, got {self.gamma}.")
        self.R = torch.eye(3, dtype=torch.float64) if self.R is None else torch.as_tensor(self.R, dtype=torch.float64)
        self.T = torch.zeros(3, dtype=torch.float64) if self.T is None else torch.as_tensor(self.T, dtype=torch.float64)
        if self.R.shape != (3, 3) or self.T.shape != (3,):
            raise ValueError(f"R must be (3, 3) and T (3,), got {tuple(self.R.shape)} and {tuple(self.T.shape)}.")

    @property
    def readout(self) -> float:
        """Seconds from the first row's exposure to the last one's: ``(H - 1) * line_time``."""
        return (self.image_size[1] - 1) * self.line_time

    def num_frames(self, duration: float) -> int:
        """Frames whose every row is exposed within ``[0, duration]`` seconds."""
        last = duration - self.start - self.readout - self.exposure
        return max(0, math.floor(last * self.fps + 1e-9) + 1) if last >= 0 else 0

    def frame_starts(self, num: int) -> Tensor:
        """:math:`(num,)` float64: start of each frame's exposure (its first row's)."""
        return self.start + torch.arange(int(num), dtype=torch.float64) / self.fps

    def frame_times(self, frame_starts: Tensor) -> Tensor:
        """The frames' times (middle of the middle row's exposure) of their starts."""
        return frame_starts + 0.5 * (self.readout + self.exposure)

    def row_times(self, frame_start: float | Tensor, rows: Tensor, offset: float | Tensor = 0.0) -> Tensor:
        """When row ``rows`` of the frame starting at ``frame_start`` is exposed, plus ``offset`` into the exposure."""
        return frame_start + rows.to(torch.float64) * self.line_time + offset

    def to_camera(self, R_rig: Tensor, t_rig: Tensor) -> tuple[Tensor, Tensor]:
        """Board poses in the rig (``x_rig = R_rig x_board + t_rig``, :math:`(..., 3, 3)`, :math:`(..., 3)`) to
        board poses in this camera."""
        R = self.R.to(R_rig)
        return R @ R_rig, (R @ t_rig.unsqueeze(-1)).squeeze(-1) + self.T.to(t_rig)

    @cached_property
    def camera(self) -> Camera:
        """The camera value (its lens' model, ``K``, the coefficients and the image size), float64."""
        return self.lens.camera(self.K, self.image_size)

    def project(self, points: Tensor) -> tuple[Tensor, Tensor]:
        """Camera-frame points :math:`(B, N, 3)` to pixels and ``ok`` (:meth:`Lens.project` through :attr:`camera`)."""
        return self.lens.project(points, self.camera)

    @cached_property
    def rays(self) -> PixelRays:
        """The rays of this camera's pixels (computed once)."""
        return self.lens.rays(self.K, self.image_size)

    def to_json(self) -> dict:
        """The camera's parameters as JSON."""
        return {
            "K": self.K.tolist(), "image_size": list(self.image_size), "lens": self.lens.to_json(), "fps": self.fps,
            "exposure": self.exposure, "line_time": self.line_time, "readout": self.readout, "start": self.start,
            "latency": self.latency, "jitter": self.jitter, "noise": self.noise, "gamma": self.gamma,
            "R": self.R.tolist(), "T": self.T.tolist(),
        }

    @classmethod
    def from_json(cls, data: dict) -> RecordingCamera:
        """The camera written by :meth:`to_json`."""
        keys = ("fps", "exposure", "line_time", "start", "latency", "jitter", "noise", "gamma")
        f64 = torch.float64
        return cls(torch.tensor(data["K"], dtype=f64), tuple(data["image_size"]), lens_from_json(data["lens"]),
                   **{k: float(data[k]) for k in keys}, R=torch.tensor(data["R"], dtype=f64),
                   T=torch.tensor(data["T"], dtype=f64))
