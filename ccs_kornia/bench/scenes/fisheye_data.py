"""Synthetic Kannala-Brandt cameras and board views with exact ground truth (for the fisheye benchmarks).

Fields of view are horizontal (``theta = FOV / 2`` at the left and right image borders; the corners of the image
see further). Boards are placed in
random directions up to the rim of the field of view (beyond 90 degrees for FOV > 180), at random tilts up to
70 degrees; a view is kept when every corner lies inside the image (5 px margin) and adjacent corners stay at
least 4 px apart (a detector's floor).
"""

from __future__ import annotations

import math

import torch

from ccs_kornia.bench.scenes.scenes import quantize
from ccs_kornia.data.render.fisheye import kb_distort_theta
from ccs_kornia.data.render.optics import psf_and_gamma
from ccs_kornia.data.render.renderer import render_chessboard
from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import Camera, rotation_matrix_to_axis_angle
from ccs_kornia.geometry.models.factory import FISHEYE

__all__ = ["random_kb_cameras", "random_board_views", "render_kb_views"]


def random_kb_cameras(num: int, fov_range=(120.0, 200.0), image_size=(640, 480), seed: int = 0):
    """K (T,3,3), D (T,4) float64 with the horizontal field of view uniform in ``fov_range`` (degrees)."""
    g = torch.Generator().manual_seed(seed)
    dt = torch.float64
    W, H = image_size
    half_diag = 0.5 * math.hypot(W, H)
    Ks, Ds = [], []
    while len(Ks) < num:
        fov = math.radians(fov_range[0] + (fov_range[1] - fov_range[0]) * float(torch.rand(1, generator=g)))
        tmax = fov / 2
        D = (torch.rand(4, generator=g, dtype=dt) - 0.5) * torch.tensor([0.1, 0.02, 0.004, 0.001], dtype=dt)
        t = torch.linspace(0, tmax * 1.05 * half_diag / (W / 2), 200, dtype=dt)  # up to the image corners
        _, slope = kb_distort_theta(t, D)
        if float(slope.min()) < 0.3:
            continue  # not monotonic enough over the field of view
        theta_d, _ = kb_distort_theta(torch.tensor(tmax, dtype=dt), D)
        f = (W / 2) / float(theta_d)
        r = torch.rand(3, generator=g, dtype=dt)
        K = torch.tensor([[f, 0, (W - 1) / 2 + 20 * (float(r[1]) - 0.5)],
                          [0, f * (1 + 0.02 * (float(r[0]) - 0.5)), (H - 1) / 2 + 20 * (float(r[2]) - 0.5)], [0, 0, 1]], dtype=dt)
        Ks.append(K)
        Ds.append(D)
    return torch.stack(Ks), torch.stack(Ds)


def _rotation_from(e3: torch.Tensor, g: torch.Generator) -> torch.Tensor:
    a = torch.randn(e3.shape, generator=g, dtype=e3.dtype)
    e1 = torch.nn.functional.normalize(a - (a * e3).sum(-1, keepdim=True) * e3, dim=-1)
    e2 = torch.linalg.cross(e3, e1)
    return torch.stack([e1, e2, e3], -1)


def random_board_views(K, D, views: int, cols: int = 9, rows: int = 6, square: float = 0.03, image_size=(640, 480),
                       fov_range=None, max_tilt_deg: float = 70.0, seed: int = 0):
    """Board poses and exact corners for each camera: rvec, tvec (T,V,3), uv (T,V,N,2), obj (N,3)."""
    g = torch.Generator().manual_seed(seed + 1)
    dt = torch.float64
    W, H = image_size
    obj = board_object_points(cols, rows, square, dtype=dt)
    centre = obj.mean(0)
    half_diag = 0.5 * math.hypot(W, H)
    T = K.shape[0]
    out_r, out_t, out_uv = [], [], []
    for c in range(T):
        Kc = K[c]
        cam = Camera.from_opencv(FISHEYE, Kc, D[c])
        # theta at the half diagonal (the field of view's rim)
        rim = cam.unproject(torch.tensor([[[Kc[0, 2] + half_diag, Kc[1, 2]]]], dtype=dt))[0]
        tmax = float(torch.atan2(rim[0, :2].norm(), rim[0, 2]))
        got_r, got_t, got_uv = [], [], []
        while len(got_r) < views:
            M = 256
            th = tmax * torch.rand(M, generator=g, dtype=dt) ** 0.25  # favour the rim
            ph = 2 * math.pi * torch.rand(M, generator=g, dtype=dt)
            d = torch.stack([th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()], -1)
            alpha = math.radians(20) + math.radians(40) * torch.rand(M, generator=g, dtype=dt)
            dist = (cols - 1) * square / (2 * (alpha / 2).tan())
            tilt = math.radians(max_tilt_deg) * torch.rand(M, generator=g, dtype=dt)
            axis = torch.nn.functional.normalize(torch.linalg.cross(d, torch.randn(M, 3, generator=g, dtype=dt)), dim=-1)
            # the board normal: the viewing direction tilted about a perpendicular axis
            e3 = d * tilt.cos()[:, None] + torch.linalg.cross(axis, d) * tilt.sin()[:, None]
            R = _rotation_from(e3, g)
            t = dist[:, None] * d - (R @ centre)
            rv = rotation_matrix_to_axis_angle(R)
            uv = cam.project(obj.expand(1, M, -1, -1), rv[None], t[None])[0]
            Xc = obj @ R.transpose(-1, -2) + t[:, None]
            theta = torch.atan2(Xc[..., :2].norm(dim=-1), Xc[..., 2])
            inside = (uv[..., 0] > 5) & (uv[..., 0] < W - 6) & (uv[..., 1] > 5) & (uv[..., 1] < H - 6) & (theta < tmax)
            grid = uv.reshape(M, rows, cols, 2)
            dx = (grid[:, :, 1:] - grid[:, :, :-1]).norm(dim=-1).flatten(1).amin(-1)
            dy = (grid[:, 1:] - grid[:, :-1]).norm(dim=-1).flatten(1).amin(-1)
            ok = inside.all(-1) & (dx > 4) & (dy > 4)
            for i in ok.nonzero().squeeze(1).tolist():
                if len(got_r) < views:
                    got_r.append(rv[i]); got_t.append(t[i]); got_uv.append(uv[i])
        out_r.append(torch.stack(got_r)); out_t.append(torch.stack(got_t)); out_uv.append(torch.stack(got_uv))
    return torch.stack(out_r), torch.stack(out_t), torch.stack(out_uv), obj


def render_kb_views(K, D, rvec, tvec, cols: int = 9, rows: int = 6, square: float = 0.03, image_size=(640, 480),
                    seed: int = 0, noise: float = 0.01, supersample: int = 4):
    """Render the views of :func:`random_board_views` through each camera's Kannala-Brandt lens, with realistic
    optics: a 0.3–1 px Gaussian point spread, a tone curve (gamma 1.8–2.4), read noise of ``noise`` (a fraction of
    full scale) and 8-bit quantisation. The image circle reaches 2 % beyond the image corners.

    Returns:
        images :math:`(T, V, 1, H, W)` float32 and the exact corners :math:`(T, V, N, 2)` float64 of the renders.

    Example:
        >>> K, D = random_kb_cameras(1, seed=0)
        >>> rvec, tvec, uv, _ = random_board_views(K, D, 2, seed=0)
        >>> images, corners = render_kb_views(K, D, rvec, tvec, supersample=1)
        >>> images.shape, bool((corners - uv).abs().max() < 1e-3)
        (torch.Size([1, 2, 1, 480, 640]), True)
    """
    g = torch.Generator().manual_seed(seed + 2)
    images, corners = [], []
    for c in range(K.shape[0]):
        v = rvec.shape[1]
        # the image's corner pixel
        ray = Camera.from_opencv(FISHEYE, K[c].double(), D[c].double()).unproject(torch.zeros(1, 1, 2, dtype=torch.float64))[0]
        fov = 2.04 * math.degrees(float(torch.atan2(ray[0, :2].norm(), ray[0, 2])))
        img, pts = render_chessboard(K[c].expand(v, 3, 3).float(), rvec[c].float(), tvec[c].float(), (cols, rows),
                                     square, image_size, fisheye=D[c].float().expand(v, 4), fov_deg=fov,
                                     background=0.2 + 0.4 * float(torch.rand(1, generator=g)), supersample=supersample)
        img = psf_and_gamma(img, g)
        img = img + noise * torch.randn(img.shape, generator=g)
        images.append(quantize(img))
        corners.append(pts.double())
    return torch.stack(images), torch.stack(corners)
