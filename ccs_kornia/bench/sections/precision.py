r"""Precision against mrcal: its published corners of a wide lens, split in halves, against its published solutions.

The set: ``mrcal_figueroa_corners`` in ``../shared/data/real`` (``$CCS_REAL_DATA``): mrcal's documentation example,
186 views of a 10x10 board (0.077 m) on a 6016x4016 wide lens, corners as mrgingham found them (``corners.vnl``, each
weighed by its level as mrcal weighs it: an inverse variance ``0.25 ** level``), and mrcal's solutions
(``LENSMODEL_OPENCV8`` and its splined model, both with the board's sag ``calobject_warp``).

Per camera model (``rational``, the same as mrcal's OPENCV8, and ``fisheye``), with a flat board and with the sag
(:mod:`~ccs_kornia.geometry.board_warp`), and mrcal's splined stereographic model on the grid of mrcal's published
solution (30 x 20 control points over 170 degrees) with the sag:

* the whole set: RMS, the sag and its 1-sigma, the residuals' structure (6 x 4 cells: RMS of the cell means, cells
  significant; :mod:`~ccs_kornia.modules.calibration.quality.residual_structure`), the fit's wall and CPU time;
* split halves, by index (alternate views) and by time (the first and the second half of the session): the held-out
  error (each half's camera on the other half's views, their poses refitted; the median over the corners of both
  directions) and the projection difference between the halves' cameras, two ways: after the rotation that aligns
  them best over the cells some board of the whole set covered, RMS over those cells (a 60 x 40 grid); and as mrcal's
  ``projection_diff`` computes it (:func:`mrcal_projection_difference`: the rotation fitted near the image's centre,
  RMS over the points of its grid that boards of both halves reached), the figure set beside mrcal's own halves;
* against mrcal's OPENCV8 and its splined solution: the projection difference of the whole-set camera from mrcal's,
  the same way.
"""

from __future__ import annotations

import ast
import base64
import io
import math
import time
from pathlib import Path

import torch

from ccs_kornia.bench.sections.real import default_real_dir
from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import RATIONAL
from ccs_kornia.geometry.models.factory import camera_model
from ccs_kornia.geometry.models.splined import SplinedStereographicModel
from ccs_kornia.io.corners_file import read_corners_vnl
from ccs_kornia.modules.calibration.board_flatness import heldout_errors
from ccs_kornia.modules.calibration.solver import CalibrationSolver

__all__ = ["SET", "load_mrcal_model", "mrcal_projection_difference", "precision_md", "projection_difference",
           "run_precision"]

#: the shared set this section runs on
SET = "mrcal_figueroa_corners"
SIZE = (6016, 4016)
#: the splined model's grid where mrcal's published solution is not there to name it (mrcal's for this lens)
SPLINED_GRID = "splined_stereographic_order=3_Nx=30_Ny=20_fov_x_deg=170"


def load_mrcal_model(path: Path) -> dict:
    """An mrcal ``.cameramodel`` (a Python dict in text): ``lensmodel``, ``intrinsics``, ``imagersize`` and, where the
    model carries its ``optimization_inputs``, the board's sag ``calobject_warp``."""
    text = path.read_text()
    data = ast.literal_eval(text[text.index("{"):])
    out = {"lensmodel": data["lensmodel"], "intrinsics": list(data["intrinsics"]), "imagersize": data["imagersize"]}
    if "optimization_inputs" in data:
        import numpy as np

        inputs = np.load(io.BytesIO(base64.b85decode(data["optimization_inputs"])), allow_pickle=False)
        out["calobject_warp"] = [float(x) for x in inputs["calobject_warp"]]
    return out


def _kabsch(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """The rotation :math:`(3, 3)` taking rays ``a`` :math:`(M, 3)` closest to ``b``."""
    u, _, vt = torch.linalg.svd(b.T @ a)
    d = torch.sign(torch.det(u @ vt))
    return u @ torch.diag(torch.tensor([1.0, 1.0, float(d)], dtype=a.dtype)) @ vt


def projection_difference(a: Camera, b: Camera, covered: torch.Tensor | None = None,
                          grid: tuple[int, int] = (60, 40)) -> float:
    """RMS (px) over a grid of the image of how far camera ``b`` projects the rays camera ``a`` sees at each pixel,
    after the rotation between them that fits best (fitted on, and measured over, the ``covered`` cells :math:`(gy, gx)`
    bool, default all).

    Example:
        >>> from ccs_kornia.geometry.models import K1K2
        >>> K = torch.tensor([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]], dtype=torch.float64)
        >>> cam = Camera.from_opencv(K1K2, K, torch.tensor([-0.1, 0.01], dtype=torch.float64), (640, 480))
        >>> projection_difference(cam, cam) < 1e-9
        True
    """
    W, H = a.image_sizes[0]
    gx, gy = grid
    ys, xs = torch.meshgrid((torch.arange(gy, dtype=torch.float64) + 0.5) * H / gy,
                            (torch.arange(gx, dtype=torch.float64) + 0.5) * W / gx, indexing="ij")
    q = torch.stack([xs, ys], -1).reshape(-1, 2)
    keep = torch.ones(q.shape[0], dtype=torch.bool) if covered is None else covered.reshape(-1)
    ra = a.unproject(q[None])[0]
    rb = b.unproject(q[None])[0]
    ok = keep & ra.isfinite().all(-1) & rb.isfinite().all(-1)
    R = _kabsch(ra[ok], rb[ok])
    uv = b.project((ra[ok] @ R.T)[None])[0]
    d = (uv - q[ok]).norm(dim=-1)
    d = d[d.isfinite()]
    return float(d.square().mean().sqrt()) if d.numel() else math.nan


def mrcal_projection_difference(a: Camera, b: Camera, seen_a: torch.Tensor, seen_b: torch.Tensor,
                                grid: tuple[int, int] = (60, 40)) -> float:
    """RMS (px) of how far camera ``b`` projects the rays camera ``a`` sees, as mrcal's ``projection_diff`` computes
    it for two calibrations that carry no uncertainty: a ``grid`` of pixels spanning the image (``0 .. W - 1`` across,
    ``0 .. H - 1`` down), the rotation between the cameras fitted over the pixels within ``min(W, H) / 6`` of the
    image's centre (its focus region), the RMS taken over the grid points whose nearest corners include corners of
    both calibrations' views (``seen_a``, ``seen_b`` :math:`(M, 2)` pixels): where both had data.

    Example:
        >>> from ccs_kornia.geometry.models import K1K2
        >>> K = torch.tensor([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]], dtype=torch.float64)
        >>> cam = Camera.from_opencv(K1K2, K, torch.tensor([-0.1, 0.01], dtype=torch.float64), (640, 480))
        >>> seen = torch.tensor([[100.0, 100.0], [320.0, 240.0]], dtype=torch.float64)
        >>> mrcal_projection_difference(cam, cam, seen, seen) < 1e-9
        True
    """
    W, H = a.image_sizes[0]
    gx, gy = grid
    ys, xs = torch.meshgrid(torch.linspace(0, H - 1, gy, dtype=torch.float64),
                            torch.linspace(0, W - 1, gx, dtype=torch.float64), indexing="ij")
    q = torch.stack([xs, ys], -1).reshape(-1, 2)

    def reached(seen: torch.Tensor) -> torch.Tensor:
        seen = seen[seen.isfinite().all(-1)]
        i = (seen[:, 0] / (W - 1) * (gx - 1)).round().long().clamp(0, gx - 1)
        j = (seen[:, 1] / (H - 1) * (gy - 1)).round().long().clamp(0, gy - 1)
        out = torch.zeros(gy, gx, dtype=torch.bool)
        out[j, i] = True
        return out.reshape(-1)

    ra = torch.nn.functional.normalize(a.unproject(q[None])[0], dim=-1)
    rb = torch.nn.functional.normalize(b.unproject(q[None])[0], dim=-1)
    focus = (q - torch.tensor([(W - 1) / 2, (H - 1) / 2], dtype=torch.float64)).norm(dim=-1) < min(W, H) / 6
    ok = focus & ra.isfinite().all(-1) & rb.isfinite().all(-1)
    R = _kabsch(ra[ok], rb[ok])
    d = (b.project((ra @ R.T)[None])[0] - q).norm(dim=-1)
    both = reached(seen_a) & reached(seen_b) & d.isfinite()
    return float(d[both].square().mean().sqrt()) if bool(both.any()) else math.nan


def _covered(corners: torch.Tensor, views: torch.Tensor, grid: tuple[int, int] = (60, 40)) -> torch.Tensor:
    gx, gy = grid
    c = corners[views].reshape(-1, 2)
    c = c[c.isfinite().all(-1)]
    col = (c[:, 0] / SIZE[0] * gx).long().clamp(0, gx - 1)
    row = (c[:, 1] / SIZE[1] * gy).long().clamp(0, gy - 1)
    out = torch.zeros(gy, gx, dtype=torch.bool)
    out[row, col] = True
    return out


def _halves(V: int) -> dict[str, torch.Tensor]:
    index = torch.arange(V)
    return {"index": torch.stack([index % 2 == 0, index % 2 == 1]),
            "time": torch.stack([index < V // 2, index >= V // 2])}


def run_precision(cfg=None, log=print) -> dict:
    """Run the section (module docstring). Returns a JSON-able dict."""
    root = Path(getattr(cfg, "real_dir", None) or default_real_dir()) / SET
    if not (root / "corners.vnl").is_file():
        return {"skipped": f"{root / 'corners.vnl'} not found"}
    models = tuple(getattr(cfg, "precision_models", ("rational", "fisheye", "splined")))
    cf = read_corners_vnl(str(root / "corners.vnl"), (10, 10))
    corners = cf.corners[None]
    valid = corners.isfinite().all(-1)
    sigma = torch.stack([v.sigma for v in cf.views])[None]
    weights = torch.where(valid, sigma.nan_to_num(1.0).pow(-2), 0.0)
    obj = board_object_points(10, 10, 0.077, dtype=torch.float64)
    V = corners.shape[1]
    mrcal = {name: load_mrcal_model(root / f"mrcal_{name}-0.cameramodel") for name in ("opencv8", "splined")
             if (root / f"mrcal_{name}-0.cameramodel").is_file()}
    reference = None
    if "opencv8" in mrcal:
        p = mrcal["opencv8"]["intrinsics"]
        K = torch.tensor([[p[0], 0, p[2]], [0, p[1], p[3]], [0, 0, 1]], dtype=torch.float64)
        reference = Camera.from_opencv(RATIONAL, K, torch.tensor(p[4:], dtype=torch.float64), SIZE)
    out: dict = {"set": SET, "views": V, "corners": int(valid.sum()),
                 "mrcal": {k: {"lensmodel": m["lensmodel"], "calobject_warp": m.get("calobject_warp")}
                           for k, m in mrcal.items()}, "models": {}}
    splined_reference = None
    if "splined" in mrcal:
        splined_reference = Camera(camera_model(mrcal["splined"]["lensmodel"]),
                                   torch.tensor(mrcal["splined"]["intrinsics"], dtype=torch.float64), SIZE)
    for name in models:
        # "splined": mrcal's splined stereographic model on the grid of mrcal's published solution, with the sag
        model = splined_reference.model if name == "splined" and splined_reference is not None else camera_model(
            SPLINED_GRID if name == "splined" else name)
        spline = isinstance(model, SplinedStereographicModel)
        for bent in ((True,) if spline else (False, True) if not model.is_fisheye else (False,)):
            key = f"{name}{' bent' if bent else ''}"
            if spline:
                key = f"splined {model.nx}x{model.ny} bent"
            solver = CalibrationSolver(model=model, board_warp=bent)
            start, cpu = time.perf_counter(), time.process_time()
            whole = solver(corners, valid, obj, SIZE, weights=weights)
            seconds = time.perf_counter() - start
            row = {"rms_px": float(whole.rms), "fit_s": seconds, "fit_cpu_s": time.process_time() - cpu,
                   "residual_structure": whole.residual_structure(0)}
            if bent:
                row["warp_mm"] = [1000 * float(x) for x in whole.board_warp[0]]
                row["warp_std_mm"] = [1000 * float(x) for x in whole.std_board_warp[0]]
            if reference is not None and not model.is_fisheye:
                row["vs_mrcal_opencv8_px"] = projection_difference(whole.camera, reference,
                                                                   _covered(corners[0], whole.used[0]))
            if splined_reference is not None:
                row["vs_mrcal_splined_px"] = projection_difference(whole.camera, splined_reference,
                                                                   _covered(corners[0], whole.used[0]))
            for split, halves in _halves(V).items():
                cams, errors = [], []
                for h in range(2):
                    part = valid & halves[h][None, :, None]
                    cams.append(solver(corners, part, obj, SIZE, weights=weights, initial=whole))
                for h in range(2):
                    errors.append(heldout_errors(cams[h], corners, valid, halves[1 - h][None], obj, whole, weights))
                e = torch.cat([x.flatten() for x in errors])
                seen = [corners[0][halves[h] & whole.used[0]].reshape(-1, 2) for h in range(2)]
                row[f"split_{split}"] = {
                    "heldout_median_px": float(e.nanmedian()),
                    "projection_difference_px": projection_difference(
                        cams[0].camera, cams[1].camera, _covered(corners[0], whole.used[0])),
                    "projection_difference_mrcal_px": mrcal_projection_difference(cams[0].camera, cams[1].camera,
                                                                                  *seen),
                }
            out["models"][key] = row
            log(f"[precision] {key}: RMS {row['rms_px']:.3f} px, held-out median {row['split_index']['heldout_median_px']:.3f} "
                f"/ {row['split_time']['heldout_median_px']:.3f} px (index / time halves), {seconds:.1f} s")
    return out


def precision_md(sec: dict) -> list[str]:
    """Markdown of :func:`run_precision`'s result."""
    if "models" not in sec:
        return [f"Not run: {sec.get('error') or sec.get('skipped', '')}"]

    def f(x, digits=3):
        return "–" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{digits}f}"

    lines = [(f"mrcal's published corners of a wide lens ({sec['views']} views, {sec['corners']} corners weighed by "
              "their level as mrcal weighs them), each model with a flat and with a bent board. Held-out: one half's "
              "camera on the other half's views (poses refitted), median over the corners of both directions; halves "
              "by index (alternate views) and by time (first and second half). Projection differences after the "
              "best rotation, RMS over a 60 x 40 grid where boards were; mrcal's way: the rotation fitted near the "
              "image's centre, RMS over its 60 x 40 grid where boards of both halves were."), "",
             ("| model | RMS px | sag mm (1-sigma) | cell means RMS px / significant | held-out median px: index / "
              "time | halves differ px: index / time | the same, mrcal's way: index / time | vs mrcal OPENCV8 px | "
              "vs mrcal splined px | fit s (CPU s) |"),
             "|---|---|---|---|---|---|---|---|---|---|"]
    for key, r in sec["models"].items():
        s = r.get("residual_structure") or {}
        warp = ("–" if "warp_mm" not in r else
                f"{r['warp_mm'][0]:+.3f} / {r['warp_mm'][1]:+.3f} ({r['warp_std_mm'][0]:.3f})")
        lines.append(f"| {key} | {f(r['rms_px'])} | {warp} | {f(s.get('rms_cell_means_px'))} / "
                     f"{s.get('cells_significant', '–')} of {s.get('cells', '–')} | "
                     f"{f(r['split_index']['heldout_median_px'])} / {f(r['split_time']['heldout_median_px'])} | "
                     f"{f(r['split_index']['projection_difference_px'])} / "
                     f"{f(r['split_time']['projection_difference_px'])} | "
                     f"{f(r['split_index'].get('projection_difference_mrcal_px'))} / "
                     f"{f(r['split_time'].get('projection_difference_mrcal_px'))} | {f(r.get('vs_mrcal_opencv8_px'))} | "
                     f"{f(r.get('vs_mrcal_splined_px'))} | {f(r['fit_s'], 2)} ({f(r.get('fit_cpu_s'), 1)}) |")
    warps = [f"{k}: {1000 * w[0]:+.3f} / {1000 * w[1]:+.3f} mm" for k, m in sec.get("mrcal", {}).items()
             if (w := m.get("calobject_warp"))]
    if warps:
        lines += ["", "mrcal's own sag (its `calobject_warp`): " + ", ".join(warps) + "."]
    return lines + [""]
