"""Board-free images for the false-board test: clutter, stripes, line grids, tiled floors, bricks, noise and
small checker patches (fewer corners than the board searched for), in perspective, through the same camera
chain (point spread, noise, gamma) as the wild renders.

Patterns are evaluated analytically on a plane seen by a virtual pinhole camera (tilt up to 60 degrees, cells
of 6-60 px), 2x2 supersampled, and composited over procedural clutter. Tiled floors use random, *not*
alternating, tile greys: an alternating floor is a chessboard and a detector would be right to find one.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ccs_kornia.data.render import augment
from ccs_kornia.data.render.lens import (
    board_homography_inverse,
    normalized_to_board,
    pixels_to_normalized,
)
from ccs_kornia.data.render.optics import apply_optics
from ccs_kornia.geometry import camera

__all__ = ["DISTRACTOR_KINDS", "board_free_images"]

#: kinds of board-free images, cycled by :func:`board_free_images`
DISTRACTOR_KINDS: tuple[str, ...] = ("clutter", "stripes", "line_grid", "tiles", "bricks", "noise", "checker_patches")


def _u(g: torch.Generator, lo: float, hi: float) -> float:
    return lo + (hi - lo) * float(torch.rand((), generator=g, dtype=torch.float64))


def _hash(i: Tensor, j: Tensor, seed: int) -> Tensor:
    """Deterministic pseudo-random values in ``[0, 1)`` per integer cell."""
    x = (i.long() * 73856093) ^ (j.long() * 19349663) ^ seed
    x = (x ^ (x >> 13)) * 1274126177
    return ((x ^ (x >> 16)) & 0xFFFF).float() / 65536.0


def _plane_coords(w: int, h: int, g: torch.Generator, cell_px: float, tilt_deg: float, sub: int = 2):
    """Plane coordinates ``(s, t)`` ``(sub*sub, H, W)`` (in cells) of supersampled pixel positions, and where the
    plane is seen in front of the camera."""
    f = float(max(w, h))
    K = torch.tensor([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]], dtype=torch.float64)[None]
    tilt, azim, roll = math.radians(_u(g, 0.0, tilt_deg)), _u(g, 0, 2 * math.pi), _u(g, -math.pi, math.pi)
    axis = torch.tensor([[math.cos(azim) * tilt, math.sin(azim) * tilt, 0.0]], dtype=torch.float64)
    R = camera.axis_angle_to_rotation_matrix(axis) @ camera.axis_angle_to_rotation_matrix(
        torch.tensor([[0.0, 0.0, roll]], dtype=torch.float64))
    z = f / cell_px  # one unit (a cell) spans cell_px at the centre
    offset = torch.tensor([_u(g, -50, 50), _u(g, -50, 50), 0.0], dtype=torch.float64)
    tvec = (torch.tensor([[0.0, 0.0, z]], dtype=torch.float64) - (R @ offset.view(3, 1)).view(1, 3))
    G = board_homography_inverse(camera.rotation_matrix_to_axis_angle(R), tvec, torch.ones(1, dtype=torch.float64),
                                  torch.float64)
    offs = (torch.arange(sub, dtype=torch.float64) + 0.5) / sub - 0.5
    ys, xs = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij")
    px = (xs[None, None] + offs.view(1, sub, 1, 1)).expand(sub, sub, h, w).reshape(1, -1, w)
    py = (ys[None, None] + offs.view(sub, 1, 1, 1)).expand(sub, sub, h, w).reshape(1, -1, w)
    xn, yn = pixels_to_normalized(px, py, K)
    s, t, front = normalized_to_board(xn, yn, G)
    return s.view(sub * sub, h, w).float(), t.view(sub * sub, h, w).float(), front.view(sub * sub, h, w)


def _pattern(kind: str, s: Tensor, t: Tensor, g: torch.Generator, seed: int, max_patch: tuple[int, int]):
    """Grey level and coverage (``alpha``) of a pattern at plane coordinates ``(s, t)``."""
    one = torch.ones_like(s)
    if kind == "stripes":
        duty = _u(g, 0.2, 0.8)
        val = torch.where(torch.remainder(s, 1.0) < duty, one * _u(g, 0.0, 0.3), one * _u(g, 0.6, 1.0))
        return val, one
    if kind == "line_grid":
        width = _u(g, 0.04, 0.15)
        on = (torch.remainder(s, 1.0) < width) | (torch.remainder(t, 1.0) < width)
        return torch.where(on, one * _u(g, 0.0, 0.3), one * _u(g, 0.5, 1.0)), one
    if kind in ("tiles", "bricks"):
        shift = torch.where(torch.remainder(torch.floor(t), 2) == 1, 0.5, 0.0) if kind == "bricks" else 0.0
        ss = s * (0.5 if kind == "bricks" else 1.0) + shift
        grey = 0.25 + 0.65 * _hash(torch.floor(ss), torch.floor(t), seed)
        grout = _u(g, 0.02, 0.1)
        on = (torch.remainder(ss, 1.0) < grout) | (torch.remainder(t, 1.0) < grout)
        return torch.where(on, one * _u(g, 0.0, 1.0), grey), one
    if kind == "checker_patches":
        # patches of at most max_patch inner corners on a sparse lattice of 12 x 12 cells
        ci, cj = torch.floor(s / 12.0), torch.floor(t / 12.0)
        present = _hash(ci, cj, seed + 1) < 0.6
        nc = 1 + torch.floor(_hash(ci, cj, seed + 2) * max_patch[0])  # inner corners along s: 1..max
        nr = 1 + torch.floor(_hash(ci, cj, seed + 3) * max_patch[1])
        ls, lt = s - ci * 12.0 - 2.0, t - cj * 12.0 - 2.0
        inside = present & (ls >= 0) & (lt >= 0) & (ls < nc + 1) & (lt < nr + 1)
        dark = torch.remainder(torch.floor(ls) + torch.floor(lt), 2) == 0
        return torch.where(dark, 0.05 * one, 0.9 * one), inside.float()
    raise ValueError(f"Unknown pattern {kind!r}.")


def board_free_images(
    num: int,
    image_size: tuple[int, int],
    generator: torch.Generator,
    kinds: tuple[str, ...] = DISTRACTOR_KINDS,
    max_patch: tuple[int, int] = (3, 2),
    optics: bool = True,
) -> tuple[Tensor, list[str]]:
    """``num`` images without any chessboard of more than ``max_patch`` inner corners.

    Args:
        num: number of images (kinds are cycled).
        image_size: ``(W, H)``.
        generator: random source.
        kinds: some of :data:`DISTRACTOR_KINDS`.
        max_patch: largest checker patch (inner corners, cols x rows) in ``checker_patches``; keep it below the
            board searched for in both orientations.
        optics: apply the realistic camera chain (0.3-1 px point spread, noise, gamma).

    Returns:
        images :math:`(num, 1, H, W)` in ``[0, 1]`` and the kind of each.

    Example:
        >>> imgs, kinds = board_free_images(2, (64, 48), torch.Generator().manual_seed(0))
        >>> imgs.shape, kinds
        (torch.Size([2, 1, 48, 64]), ['clutter', 'stripes'])
    """
    w, h = int(image_size[0]), int(image_size[1])
    g = generator
    out, names = [], []
    for n in range(int(num)):
        kind = kinds[n % len(kinds)]
        seed = int(torch.randint(0, 2**30, (), generator=g))
        bg = augment.textured_background(1, (w, h), g, num_rects=10, num_lines=10, num_blobs=5, num_stripes=2)[0, 0]
        if kind == "clutter":
            img = bg
        elif kind == "noise":
            cell = _u(g, 1.0, 6.0)
            gh, gw = max(2, int(h / cell)), max(2, int(w / cell))
            noise = torch.rand(1, 1, gh, gw, generator=g, dtype=torch.float32)
            img = torch.nn.functional.interpolate(noise, size=(h, w), mode="bilinear", align_corners=False)[0, 0]
        else:
            cell = _u(g, 6.0, 60.0) if kind != "checker_patches" else _u(g, 8.0, 40.0)
            s, t, front = _plane_coords(w, h, g, cell, 60.0)
            val, alpha = _pattern(kind, s, t, g, seed, max_patch)
            alpha = alpha * front.float()
            if kind != "checker_patches":  # the pattern covers a random rectangle of the plane near the centre
                span = _u(g, 0.3, 1.2) * max(w, h) / cell
                sc, tc = float(s[0, h // 2, w // 2]), float(t[0, h // 2, w // 2])
                s0, t0 = sc - span * _u(g, 0.2, 0.8), tc - span * _u(g, 0.2, 0.8)
                alpha = alpha * ((s > s0) & (s < s0 + span) & (t > t0) & (t < t0 + span)).float()
            img = (bg * (1 - alpha) + val * alpha).mean(0)
        out.append(img.float()[None, None])
        names.append(kind)
    images = torch.cat(out)
    if optics:
        b = images.shape[0]
        centre = torch.tensor([[(w - 1) / 2, (h - 1) / 2]], dtype=torch.float64).expand(b, 2)
        # gamma 1 on these: their grey levels are already display values
        images = apply_optics(images, g, torch.full((b,), 20.0), centre, torch.full((b,), float(min(w, h))),
                              gamma=(1.0, 1.0), noise_sigma=(0.0, 0.01))
    return images.clamp(0, 1), names
