"""``ccs_kornia compare``: how far two calibrations of one camera project the same ray apart, over the image, beside
what their uncertainty explains (mrcal's ``show-projection-diff``; docs/command_line.md).

The ray that calibration A sees at each pixel of a grid is projected by calibration B, after the rotation between the
two camera frames that best aligns them is fitted out (a calibration cannot tell a small camera rotation from a
principal-point shift: mrcal's implied transformation, rotation only, for points far away). The rotation is fitted
where both calibrations saw boards (where each one's projection uncertainty is at most its worst over its boards),
over the whole image when the files do not record their uncertainty. Where both record it, the difference their
1-sigma predict (``sqrt(ua^2 + ub^2)``) is set beside the one found: calibrations that differ by much more than that
disagree for a reason their data does not show (a different lens state, a model that does not fit, a bent board).
"""

from __future__ import annotations

import argparse
import math
import os

import numpy as np
import torch

from ccs_kornia.commands._output_paths import check_outputs
from ccs_kornia.io.files import write_json
from ccs_kornia.modules.calibration.quality.uncertainty import (
    image_points,
    projection_difference,
)
from ccs_kornia.outputs.calibration_file import (
    CalibrationFile,
    RigFileError,
    read_calibration,
)
from ccs_kornia.outputs.report.drawing import write_png
from ccs_kornia.outputs.report.quality import grid_map_plot
from ccs_kornia.runtime.errors import UserError

__all__ = ["AGREE_RATIO", "run"]

#: calibrations whose difference is at most this many times what their 1-sigma predict agree within their uncertainty
AGREE_RATIO = 2.0
#: the comparison grid (across, down) when neither file records its uncertainty grid
DEFAULT_GRID = (16, 12)


def _read(path: str, camera: str | None) -> CalibrationFile:
    try:
        return read_calibration(path, camera=camera)
    except RigFileError as err:
        raise UserError(f"{path}: {err}; say which camera with --camera") from None
    except (OSError, ValueError) as err:
        raise UserError(f"{path}: {err}") from None


def _uncertainty(cal: CalibrationFile, grid: tuple[int, int]) -> tuple[np.ndarray | None, float | None]:
    """The file's 1-sigma over the grid (down, across) and its worst where its boards were, when it records them on
    this grid."""
    values = cal.diagnostics.get("uncertainty_grid_px")
    if not values or len(values) != grid[1] or len(values[0]) != grid[0]:
        return None, None
    covered = cal.diagnostics.get("uncertainty_covered_px")
    return np.array([[np.nan if v is None else v for v in row] for row in values], np.float64), covered


def _rms(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if x.size else None


def _r(x: float | None, digits: int = 4) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), digits)


def run(args: argparse.Namespace) -> int:
    check_outputs(files=[("--output", args.output), ("--plot", args.plot)])
    a, b = _read(args.first, args.camera), _read(args.second, args.camera)
    size_a, size_b = a.camera.image_size, b.camera.image_size
    if tuple(size_a) != tuple(size_b):
        raise UserError(f"the calibrations are of images of different sizes ({size_a[0]}x{size_a[1]} and "
                        f"{size_b[0]}x{size_b[1]}): not the same camera at the same resolution.")
    grid = DEFAULT_GRID
    for cal in (a, b):
        g = cal.diagnostics.get("uncertainty_grid_px")
        if g and g[0]:
            grid = (len(g[0]), len(g))
            break
    ua, covered_a = _uncertainty(a, grid)
    ub, covered_b = _uncertainty(b, grid)
    px = image_points(tuple(size_a), grid)
    # where both saw boards: each one's uncertainty at most its worst over its boards (all the image when unknown)
    region = np.ones(grid[1] * grid[0], bool)
    for u, worst in ((ua, covered_a), (ub, covered_b)):
        if u is not None and worst is not None:
            region &= (u.reshape(-1) <= worst * (1 + 1e-9)) & np.isfinite(u.reshape(-1))
    if region.sum() < 3:
        region[:] = True
    diff = projection_difference(a.camera.to(dtype=torch.float64), b.camera.to(dtype=torch.float64), px,
                                 compensate_rotation=torch.from_numpy(region))[0].numpy()
    d_grid = diff.reshape(grid[1], grid[0])
    finite = np.isfinite(diff)
    if not finite.any():
        raise UserError(f"{args.first}: its model has no inverse over the image: nothing to compare.")
    k = int(np.nanargmax(np.where(finite, diff, -np.inf)))
    expected = np.sqrt(ua**2 + ub**2).reshape(-1) if ua is not None and ub is not None else None
    rms_region = _rms(diff[region])
    exp_region = _rms(expected[region]) if expected is not None else None
    ratio = rms_region / exp_region if rms_region is not None and exp_region else None
    verdict = ("not judged (a file does not record its projection uncertainty)" if ratio is None else
               "agree within their uncertainty" if ratio <= AGREE_RATIO else
               f"differ by {ratio:.1f}x what their uncertainty explains")
    record = {
        "first": os.path.abspath(args.first), "second": os.path.abspath(args.second), "camera": args.camera,
        "image_size": list(size_a), "models": [a.camera.model.name, b.camera.model.name],
        "grid": list(grid), "rotation_fitted_over": "where both saw boards" if not region.all() else "the whole image",
        "region_fraction": round(float(region.mean()), 4),
        "rms_px": _r(_rms(diff)), "median_px": _r(float(np.nanmedian(diff))), "max_px": _r(float(diff[k])),
        "max_at_px": [round(float(v), 1) for v in px[k].tolist()],
        "region_rms_px": _r(rms_region), "region_max_px": _r(float(np.nanmax(np.where(region, diff, np.nan)))),
        "expected_region_rms_px": _r(exp_region), "ratio": _r(ratio, 3), "verdict": verdict,
        "difference_grid_px": [[_r(v) for v in row] for row in d_grid.tolist()],
        "expected_grid_px": None if expected is None else [[_r(v) for v in row]
                                                           for row in expected.reshape(grid[1], grid[0]).tolist()],
    }
    print(f"{args.second} against {args.first} ({record['models'][1]} and {record['models'][0]}, "
          f"{size_a[0]}x{size_a[1]}): the same ray lands {record['rms_px']:.3f} px apart (RMS over the image), "
          f"{record['max_px']:.3f} px at most (at {record['max_at_px'][0]:.0f}, {record['max_at_px'][1]:.0f})")
    where = f"where both saw boards ({100 * region.mean():.0f} % of the image)" if not region.all() else "over the image"
    line = f"{where}: RMS {rms_region:.3f} px"
    if exp_region is not None:
        line += f", their 1-sigma predict {exp_region:.3f} px"
    print(f"{line}: {verdict}")
    written = []
    if args.output:
        write_json(args.output, record)
        written.append(args.output)
    if args.plot:
        # one colour scale for both maps: the difference found and the one the 1-sigma predict read alike
        top = float(np.nanpercentile(diff, 95))
        if expected is not None and np.isfinite(expected).any():
            top = max(top, float(np.nanpercentile(expected, 95)))
        fig = grid_map_plot(tuple(size_a), record["difference_grid_px"],
                            "Projection difference (px) of the two calibrations, rotation fitted out",
                            "difference (px)", vmax=top)
        if record["expected_grid_px"] is not None:
            fig = np.vstack([fig, grid_map_plot(tuple(size_a), record["expected_grid_px"],
                                                "The difference their 1-sigma predict (px)", "expected (px)",
                                                vmax=top)])
        write_png(args.plot, fig, written)
    if written:
        print("wrote " + ", ".join(written))
    return 0
