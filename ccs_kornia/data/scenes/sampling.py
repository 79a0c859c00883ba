"""Random distortions and board poses for the renderer (seeded by a ``torch.Generator``)."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ccs_kornia.data.batching import (
    batched_argument,
    board_size_tensors,
    check_image_size,
    padded_object_points,
)
from ccs_kornia.data.random_draws import seeded_rand, seeded_randint, seeded_uniform
from ccs_kornia.data.render.lens import project_board, undistort_opencv_pixels
from ccs_kornia.geometry import camera
from ccs_kornia.geometry.radial import radial_undistort_points

__all__ = ["RADIAL_LEVELS", "sample_radial_distortion", "sample_opencv_distortion", "sample_poses", "sample_poses_batched"]

#: radial distortion levels of the paper's model (``mild`` is accepted as an alias of ``level1``)
RADIAL_LEVELS: tuple[str, ...] = ("none", "level1", "level2", "severe", "graded")


def _corner_radius(image_size: tuple[int, int]) -> float:
    w, h = image_size
    return 0.5 * math.hypot(w - 1, h - 1) / max(w, h)


def sample_radial_distortion(
    num: int, level: str, image_size: tuple[int, int], generator: torch.Generator, device="cpu"
) -> Tensor:
    """Paper radial coefficients ``(k0, k1, k2)`` for a named level.

    * ``none``: ``(1, 0, 0)``;
    * ``level1`` (alias ``mild``): ``k0 = 1``, ``k1 ~ U[-0.35, -0.2]``, ``k2 ~ U[-0.1, 0]``;
    * ``level2``: ``k0 ~ U[0.8, 1.2]``, ``k1 ~ U[-0.5, -0.35]``, ``k2 ~ U[-0.3, -0.1]`` (the paper's ranges;
      with radii in units of ``max(W, H)`` some of these fold before the image corner, which then
      renders black);
    * ``severe``: barrel distortion that moves the farthest image corner inwards by 15-25 % of its ideal
      radius (``1 - r_d / r_c``), with ``k0 ~ U[0.95, 1.05]`` and ``k2 / k1 ~ U[-0.2, 0.5]``, monotonic
      over the whole image;
    * ``graded``: like ``severe`` but with the corner displacement drawn from 0 to 25 % and ``k0 = 1``, so
      every strength from none to severe occurs (a smooth regression target for the distortion CNN);
    * ``any``: one of ``level1``, ``level2``, ``severe`` per view.

    Returns:
        :math:`(num, 3)` float32.
    """
    if level == "mild":
        level = "level1"
    if level not in (*RADIAL_LEVELS, "any"):
        raise ValueError(f"Unknown radial level {level!r}; expected one of {(*RADIAL_LEVELS, 'mild', 'any')}.")
    n = int(num)
    out = torch.zeros(n, 3, dtype=torch.float64)
    out[:, 0] = 1.0
    if n == 0 or level == "none":
        return out.to(device=device, dtype=torch.float32)
    if level == "any":
        which = seeded_randint(generator, 0, 2, (n,), "cpu")
        for k, name in enumerate(("level1", "level2", "severe")):
            idx = (which == k).nonzero().squeeze(1)
            if idx.numel():
                out[idx] = sample_radial_distortion(idx.numel(), name, image_size, generator).double()
        return out.to(device=device, dtype=torch.float32)
    if level == "level1":
        out[:, 1] = seeded_uniform(generator, (n,), -0.35, -0.2, "cpu")
        out[:, 2] = seeded_uniform(generator, (n,), -0.1, 0.0, "cpu")
    elif level == "level2":
        out[:, 0] = seeded_uniform(generator, (n,), 0.8, 1.2, "cpu")
        out[:, 1] = seeded_uniform(generator, (n,), -0.5, -0.35, "cpu")
        out[:, 2] = seeded_uniform(generator, (n,), -0.3, -0.1, "cpu")
    else:  # severe / graded: parameterised by the displacement of the farthest image corner
        graded = level == "graded"
        r_corner = _corner_radius(image_size)
        todo = torch.arange(n)
        for _ in range(100):
            m = todo.numel()
            disp = seeded_uniform(generator, (m,), 0.0 if graded else 0.15, 0.25, "cpu")
            k0 = torch.ones(m, dtype=torch.float64) if graded else seeded_uniform(generator, (m,), 0.95, 1.05, "cpu")
            ratio = seeded_uniform(generator, (m,), -0.2, 0.5, "cpu")
            rc = r_corner / (1.0 - disp)
            k1 = ((1.0 - disp) - k0) / (rc**2 + ratio * rc**4)
            k2 = ratio * k1
            slope = k0 + 3 * k1 * rc**2 + 5 * k2 * rc**4  # must stay increasing up to the corner
            ok = (slope > 0.1) & (k1 <= 0)
            out[todo[ok]] = torch.stack([k0, k1, k2], -1)[ok]
            todo = todo[~ok]
            if todo.numel() == 0:
                break
        if todo.numel():
            raise RuntimeError("Could not sample severe radial distortion; this should not happen.")
    return out.to(device=device, dtype=torch.float32)


def sample_opencv_distortion(
    K: Tensor,
    image_size: tuple[int, int],
    num: int,
    generator: torch.Generator,
    k1_range: tuple[float, float] = (-0.4, 0.1),
    k2_range: tuple[float, float] = (-0.05, 0.15),
    p_range: float = 2e-3,
) -> Tensor:
    """OpenCV coefficients ``(k1, k2, p1, p2, 0)`` that stay invertible over the whole image.

    ``k1 ~ U[k1_range]``, ``k2 ~ U[k2_range]``, ``p1, p2 ~ U[-p_range, p_range]``; draws whose radial factor
    stops growing (slope below 0.15) before reaching the farthest image corner are redrawn, and after
    many failures ``k1, k2`` are shrunk towards zero (wide-angle cameras tolerate only mild barrel).

    Args:
        K: :math:`(3, 3)` or :math:`(num, 3, 3)`.
        image_size: ``(W, H)``.
        num: number of coefficient sets.
        generator: random source.

    Returns:
        :math:`(num, 5)` float32 on ``K``'s device.
    """
    w, h = check_image_size(image_size)
    n = int(num)
    Kd = batched_argument(K, n, (3, 3), "K", "cpu", torch.float64)
    out = torch.zeros(n, 5, dtype=torch.float64)
    if n == 0:
        return out.to(device=K.device, dtype=torch.float32)
    fx, fy, cx, cy = Kd[:, 0, 0], Kd[:, 1, 1], Kd[:, 0, 2], Kd[:, 1, 2]
    xs = torch.tensor([0.0, w - 1.0, 0.0, w - 1.0], dtype=torch.float64)
    ys = torch.tensor([0.0, 0.0, h - 1.0, h - 1.0], dtype=torch.float64)
    r_need = (((xs - cx[:, None]) / fx[:, None]) ** 2 + ((ys - cy[:, None]) / fy[:, None]) ** 2).sqrt().amax(-1) * 1.03
    r = torch.linspace(0.0, 5.0, 2001, dtype=torch.float64)
    r2 = r * r
    todo = torch.arange(n)
    shrink = 1.0
    for attempt in range(200):
        m = todo.numel()
        k1 = seeded_uniform(generator, (m,), *k1_range, "cpu") * shrink
        k2 = seeded_uniform(generator, (m,), *k2_range, "cpu") * shrink
        p = seeded_uniform(generator, (m, 2), -p_range, p_range, "cpu")
        g = r * (1 + k1[:, None] * r2 + k2[:, None] * r2 * r2)
        slope = 1 + 3 * k1[:, None] * r2 + 5 * k2[:, None] * r2 * r2
        # largest distorted radius reached while the slope stays healthy
        healthy = torch.cumprod((slope > 0.15).to(torch.float64), -1)
        reach = (g * healthy).amax(-1)
        ok = reach >= r_need[todo]
        cand = torch.stack([k1, k2, p[:, 0], p[:, 1], torch.zeros_like(k1)], -1)
        out[todo[ok]] = cand[ok]
        todo = todo[~ok]
        if todo.numel() == 0:
            break
        if attempt % 20 == 19:
            shrink *= 0.7
    return out.to(device=K.device, dtype=torch.float32)


def _rotation_from_angles(roll: Tensor, tilt: Tensor, azimuth: Tensor) -> Tensor:
    """``R = R_tilt R_roll``: in-plane rotation of the board, then a tilt about an image-plane axis."""
    zeros = torch.zeros_like(roll)
    r_roll = camera.axis_angle_to_rotation_matrix(torch.stack([zeros, zeros, roll], -1))
    axis = torch.stack([azimuth.cos(), azimuth.sin(), zeros], -1)
    r_tilt = camera.axis_angle_to_rotation_matrix(axis * tilt.unsqueeze(-1))
    return r_tilt @ r_roll


def sample_poses_batched(
    K: Tensor,
    cols: Tensor,
    rows: Tensor,
    square: Tensor,
    image_size: tuple[int, int],
    generator: torch.Generator,
    dist: Tensor | None,
    radial: Tensor | None,
    margin: float,
    max_tilt_deg: float,
    fill_range: tuple[float, float],
    max_roll_deg: float,
    min_square_px: float,
    partial: Tensor | None = None,
    min_visible: float = 0.3,
    candidates: int = 24,
    max_rounds: int = 60,
    square_px: Tensor | None = None,
    min_tilt_deg: float = 0.0,
    cut: Tensor | None = None,
    strict: bool = True,
) -> tuple[Tensor, Tensor] | tuple[Tensor, Tensor, Tensor]:
    """:func:`sample_poses` for batches of views that each have their own camera, board and lens, with the options
    of the training scenes: rejection sampling of one pose per view, ``candidates`` proposals per pending view per
    round.

    Everything is float64 on the CPU (a few thousand points per round).

    Args:
        K: :math:`(B, 3, 3)` float64.
        cols, rows: :math:`(B,)` long inner corners; square: :math:`(B,)` float64 square sides.
        image_size: ``(W, H)``.
        generator: random source (draws happen on its device).
        dist: :math:`(B, 5)` OpenCV coefficients or ``None``; radial: :math:`(B, 3)` paper coefficients or ``None``.
        margin, max_tilt_deg, fill_range, max_roll_deg, min_square_px: as in :func:`sample_poses`.
        partial: optional :math:`(B,)` bool, views whose board may leave the image (at least ``min_visible`` of
            its corners inside).
        min_visible: the fraction of a partial view's corners inside the image.
        candidates: proposals per pending view per round; max_rounds: rounds before giving up.
        square_px: optional :math:`(B,)`, the distance such that a fronto-parallel square spans that many pixels
            (instead of ``fill_range``).
        min_tilt_deg: forces steep views.
        cut: optional :math:`(B,)` bool, views whose inner corners are all inside the image while the board's outer
            squares cross the image border.
        strict: raise when some view finds no pose.

    Returns:
        rvec, tvec :math:`(B, 3)` float64; with ``strict=False``, ``(rvec, tvec, done)`` with ``done`` :math:`(B,)`
        bool (the poses of views not done are zeros; the caller falls back).

    Raises:
        RuntimeError: some view finds no pose and ``strict`` is true.

    Example:
        >>> K = torch.tensor([[400.0, 0, 319.5], [0, 400, 239.5], [0, 0, 1]], dtype=torch.float64).expand(2, 3, 3)
        >>> rvec, tvec, done = sample_poses_batched(
        ...     K, torch.tensor([9, 5]), torch.tensor([6, 4]), torch.tensor([0.025, 0.03], dtype=torch.float64),
        ...     (640, 480), torch.Generator().manual_seed(0), None, None, 10.0, 50.0, (0.25, 0.8), 180.0, 6.0,
        ...     strict=False)
        >>> rvec.shape, done.tolist()
        (torch.Size([2, 3]), [True, True])
    """
    w, h = image_size
    b = K.shape[0]
    rvec_out = torch.zeros(b, 3, dtype=torch.float64)
    tvec_out = torch.zeros(b, 3, dtype=torch.float64)
    done = torch.zeros(b, dtype=torch.bool)
    n_max = int((cols * rows).max())
    part = torch.zeros(b, dtype=torch.bool) if partial is None else partial.cpu()
    cut_all = torch.zeros(b, dtype=torch.bool) if cut is None else cut.cpu()
    for _ in range(max_rounds):
        pend = (~done).nonzero().squeeze(1)
        if pend.numel() == 0:
            break
        m = candidates
        sel = pend.repeat_interleave(m)
        pm = sel.numel()
        Kc, cc, rc, sc, pc, cutc = K[sel], cols[sel], rows[sel], square[sel], part[sel], cut_all[sel]
        dc = None if dist is None else dist[sel]
        radc = None if radial is None else radial[sel]
        roll = seeded_uniform(generator, (pm,), -1.0, 1.0, "cpu") * math.radians(max_roll_deg)
        tilt = seeded_uniform(generator, (pm,), math.radians(min(min_tilt_deg, max_tilt_deg)), math.radians(max_tilt_deg), "cpu")
        azim = seeded_uniform(generator, (pm,), 0.0, 2 * math.pi, "cpu")
        fill = seeded_uniform(generator, (pm,), float(fill_range[0]), float(fill_range[1]), "cpu")
        pos = seeded_rand(generator, (pm, 2), "cpu")
        R = _rotation_from_angles(roll, tilt, azim)
        # distance from the fronto-parallel bounding box of the (rolled) checker area
        wb, hb = (cc + 1).double() * sc, (rc + 1).double() * sc
        ex = roll.cos().abs() * wb + roll.sin().abs() * hb
        ey = roll.sin().abs() * wb + roll.cos().abs() * hb
        fx, fy = Kc[:, 0, 0], Kc[:, 1, 1]
        z = torch.maximum(fx * ex / (fill * w), fy * ey / (fill * h))
        if square_px is not None:
            z = torch.sqrt(fx * fy) * sc / square_px[sel].double()
        bx, by = fx * ex / z, fy * ey / z
        lo_x, hi_x = margin + 0.5 * bx, w - 1 - margin - 0.5 * bx
        lo_y, hi_y = margin + 0.5 * by, h - 1 - margin - 0.5 * by
        # a board too large to fit with margin is centred (and most likely rejected)
        too_wide, too_tall = lo_x > hi_x, lo_y > hi_y
        lo_x = torch.where(too_wide, torch.full_like(lo_x, (w - 1) / 2), lo_x)
        hi_x = torch.where(too_wide, torch.full_like(hi_x, (w - 1) / 2), hi_x)
        lo_y = torch.where(too_tall, torch.full_like(lo_y, (h - 1) / 2), lo_y)
        hi_y = torch.where(too_tall, torch.full_like(hi_y, (h - 1) / 2), hi_y)
        # partial views may put the centre up to a third of the board outside the image; cut views sit
        # near the border so that the outer squares leave the image
        loose = pc | cutc
        lo_x = torch.where(loose, torch.where(cutc, 0.5 * bx - 1.5 * bx / (cc + 1), -0.3 * bx), lo_x)
        hi_x = torch.where(loose, torch.where(cutc, w - 1 - 0.5 * bx + 1.5 * bx / (cc + 1), w - 1 + 0.3 * bx), hi_x)
        lo_y = torch.where(loose, torch.where(cutc, 0.5 * by - 1.5 * by / (rc + 1), -0.3 * by), lo_y)
        hi_y = torch.where(loose, torch.where(cutc, h - 1 - 0.5 * by + 1.5 * by / (rc + 1), h - 1 + 0.3 * by), hi_y)
        target = torch.stack([lo_x + (hi_x - lo_x) * pos[:, 0], lo_y + (hi_y - lo_y) * pos[:, 1]], -1).unsqueeze(1)
        # the target is a distorted pixel: find the ideal pixel it comes from
        if radc is not None:
            target = radial_undistort_points(target, radc, image_size)
        if dc is not None and bool((dc != 0).any()):
            target, _ = undistort_opencv_pixels(target, Kc, dc)
        ray = torch.cat([target[:, 0], torch.ones(pm, 1, dtype=torch.float64)], -1)
        ray = torch.linalg.solve(Kc, ray.unsqueeze(-1)).squeeze(-1)
        centre = torch.stack([(cc - 1).double() * sc / 2, (rc - 1).double() * sc / 2, torch.zeros_like(sc)], -1)
        tvec = z.unsqueeze(-1) * ray - (R @ centre.unsqueeze(-1)).squeeze(-1)
        rvec = camera.rotation_matrix_to_axis_angle(R)
        obj, exists = padded_object_points(cc, rc, sc, n_max)
        pix, ok = project_board(obj, Kc, rvec, tvec, image_size, dc, radc)
        finite = torch.isfinite(pix).all(-1)
        inside = (
            ok & finite
            & (pix[..., 0] >= margin) & (pix[..., 0] <= w - 1 - margin)
            & (pix[..., 1] >= margin) & (pix[..., 1] <= h - 1 - margin)
        )
        full_ok = (inside | ~exists).all(-1)
        vis_frac = (inside & exists).sum(-1).double() / exists.sum(-1).double()
        part_ok = (vis_frac >= min_visible) & ((ok & finite) | ~exists).all(-1)
        # smallest spacing between neighbouring corners (horizontal and vertical) must be resolvable
        n = torch.arange(n_max).unsqueeze(0)
        nb_h = n + 1
        has_h = exists & (torch.remainder(n, cc.unsqueeze(1)) < (cc - 1).unsqueeze(1))
        nb_v = n + cc.unsqueeze(1)
        has_v = exists & (nb_v < (cc * rc).unsqueeze(1))
        safe = torch.where(finite.unsqueeze(-1), pix, torch.zeros_like(pix))
        d_h = (safe.gather(1, nb_h.clamp_max(n_max - 1).expand(pm, -1).unsqueeze(-1).expand(-1, -1, 2)) - safe).norm(dim=-1)
        d_v = (safe.gather(1, nb_v.clamp_max(n_max - 1).unsqueeze(-1).expand(-1, -1, 2)) - safe).norm(dim=-1)
        d_h = torch.where(has_h, d_h, torch.full_like(d_h, math.inf)).amin(-1)
        d_v = torch.where(has_v, d_v, torch.full_like(d_v, math.inf)).amin(-1)
        spacing_ok = torch.minimum(d_h, d_v) >= min_square_px
        valid = torch.where(pc, part_ok, full_ok) & spacing_ok & torch.isfinite(tvec).all(-1)
        if bool(cutc.any()):
            valid &= ~cutc | _outer_squares_cut(Kc, rvec, tvec, cc, rc, sc, image_size, dc, radc)
        valid = valid.view(-1, m)
        got = valid.any(-1)
        first = valid.to(torch.uint8).argmax(-1)
        pick = torch.arange(pend.numel()) * m + first
        rvec_out[pend[got]] = rvec[pick[got]]
        tvec_out[pend[got]] = tvec[pick[got]]
        done[pend[got]] = True
    if not strict:
        return rvec_out, tvec_out, done
    if not bool(done.all()):
        raise RuntimeError(
            f"Could not place {int((~done).sum())} board(s) inside the image with margin {margin}px; "
            "relax margin, fill_range or max_tilt_deg, or use a smaller board."
        )
    return rvec_out, tvec_out


def _outer_squares_cut(K, rvec, tvec, cols, rows, square, image_size, dist, radial) -> Tensor:
    """Whether some outer corner of the checker area (the board's outermost squares) falls outside the image."""
    w, h = image_size
    z = torch.zeros_like(square)
    outer = torch.stack([
        torch.stack([-square, -square, z], -1), torch.stack([cols.double() * square, -square, z], -1),
        torch.stack([-square, rows.double() * square, z], -1), torch.stack([cols.double() * square, rows.double() * square, z], -1),
    ], 1)
    pix, ok = project_board(outer, K, rvec, tvec, image_size, dist, radial)
    out = (pix[..., 0] < 0) | (pix[..., 0] > w - 1) | (pix[..., 1] < 0) | (pix[..., 1] > h - 1) | ~ok
    return out.any(-1)


def sample_poses(
    K: Tensor,
    board_size: tuple[int, int],
    square: float,
    image_size: tuple[int, int],
    num: int,
    generator: torch.Generator,
    dist: Tensor | None = None,
    radial: Tensor | None = None,
    margin: float = 10.0,
    max_tilt_deg: float = 50.0,
    fill_range: tuple[float, float] = (0.25, 0.8),
    max_roll_deg: float = 180.0,
    min_square_px: float = 6.0,
) -> tuple[Tensor, Tensor]:
    """Random board poses with every inner corner inside the image (with ``margin`` pixels to spare).

    Batched rejection sampling: for every pose still missing, ``24`` candidates are drawn at once
    (in-plane roll up to ``max_roll_deg``, tilt up to ``max_tilt_deg`` about a random image-plane axis,
    distance so the board's bounding box spans ``fill_range`` of the image, centre anywhere it fits) and
    the first that keeps all corners inside the image, inside the non-folding part of the distortion
    models and at least ``min_square_px`` apart is kept.

    Args:
        K: :math:`(3, 3)` or :math:`(num, 3, 3)`.
        board_size: ``(cols, rows)`` inner corners.
        square: square side in world units.
        image_size: ``(W, H)``.
        num: number of poses.
        generator: random source (CPU generator recommended; draws happen on its device).
        dist: optional OpenCV coefficients :math:`(5,)` or :math:`(num, 5)`.
        radial: optional paper coefficients :math:`(3,)` or :math:`(num, 3)`.

    Returns:
        rvec :math:`(num, 3)`, tvec :math:`(num, 3)` in ``K``'s floating dtype and device.

    Example:
        >>> K = torch.tensor([[400., 0, 319.5], [0, 400, 239.5], [0, 0, 1]])
        >>> r, t = sample_poses(K, (9, 6), 0.025, (640, 480), 4, torch.Generator().manual_seed(0))
        >>> r.shape, t.shape
        (torch.Size([4, 3]), torch.Size([4, 3]))
    """
    w, h = check_image_size(image_size)
    n = int(num)
    if n < 1:
        raise ValueError(f"num must be >= 1, got {num}.")
    lo, hi = float(fill_range[0]), float(fill_range[1])
    if not 0 < lo <= hi:
        raise ValueError(f"fill_range must satisfy 0 < low <= high, got {fill_range}.")
    out_dtype = K.dtype if K.is_floating_point() else torch.float32
    Kd = batched_argument(K, n, (3, 3), "K", "cpu", torch.float64)
    dd = batched_argument(dist, n, (5,), "dist", "cpu", torch.float64)
    rd = batched_argument(radial, n, (3,), "radial", "cpu", torch.float64)
    cols, rows = board_size_tensors(board_size, n, "cpu")
    sq = torch.full((n,), float(square), dtype=torch.float64)
    rvec, tvec = sample_poses_batched(
        Kd, cols, rows, sq, (w, h), generator, dd, rd, float(margin), float(max_tilt_deg), (lo, hi),
        float(max_roll_deg), float(min_square_px),
    )
    return rvec.to(device=K.device, dtype=out_dtype), tvec.to(device=K.device, dtype=out_dtype)
