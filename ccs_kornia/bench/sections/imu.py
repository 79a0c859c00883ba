r"""Camera-IMU benchmark: the fit against the truth on rendered visual-inertial recordings.

**Rendered recordings** (:func:`~ccs_kornia.data.recordings.visual_inertial.visual_inertial_recording`): a camera
(EuRoC's cam0: 752x480, radial-tangential) with an IMU at a random pose on it (any rotation, up to 10 cm away),
swung by hand in front of a 7x6-point board for ``imu_seconds`` s (smooth analytic motion, not a spline: 0.15-1.6 Hz,
about 0.5 rad about each axis and 0.2 m along each), global shutter at 20 fps, corners with 0.2 px noise; an IMU at
200 Hz with EuRoC's ADIS16448 noise and bias random walk; a time offset drawn in -30 .. +30 ms. Seeds start at
:data:`SEED` (the tests and doctests use seeds below 1000).

Conditions: the IMU's noise given as it is (``given``), given 10x too large (``noise x10``) and 10x too small
(``noise /10``), as users' ``imu.yaml`` files are (Kalibr's users report values 10-20x off); a stereo rig
(``stereo``, two cameras 11 cm apart, the noise given; ``stereo, rig held``: the same with the rig's extrinsics given
and held, one ``T_cam_imu`` fitted); a rolling-shutter camera (``rolling shutter``: rows read 30 us apart, 14 ms for
the frame; fitted with its row delay); an IMU with intrinsic errors as a MEMS part has them (``IMU errors``: scale
factors within +-1.5 %, axes misaligned and the gyroscope rotated by up to 5 mrad, g-sensitivity up to 3e-4 rad/s per
m/s^2, drawn per trial), fitted as an ideal IMU (``IMU errors, ideal model``) and with Kalibr's scale-misalignment
model (``IMU errors, scale-misalignment``: the intrinsics' largest error reported too); the board's sag judged
(``given, sag judged``: the ``given`` recordings fitted as the command line fits them, the sag fitted and kept where
held-out frames say it helps); a board bent by :data:`BENT` (``bent board, flat``: fitted as flat; ``bent board, sag
judged``: the same recordings, the sag judged: the sag's error and whether it was kept reported too).

Per trial: each camera's ``T_cam_imu`` error (rotation degrees, translation mm) and time-offset error (ms); the
honesty of the 1-sigma: the fraction of the error's components (3 rotation, 3 translation, 1 time offset per camera)
within their 1-sigma (68 % for an honest Gaussian sigma); the fit's wall time; the process's peak memory after the
section (an upper bound of the fit's).
"""

from __future__ import annotations

import math
import resource
import statistics
from typing import NamedTuple

import torch

from ccs_kornia.data.recordings.visual_inertial import visual_inertial_recording
from ccs_kornia.geometry.imu_intrinsics import ImuIntrinsics, ImuModel
from ccs_kornia.geometry.so3 import exp_so3, log_so3
from ccs_kornia.modules.imu.problem import ImuCameraData
from ccs_kornia.modules.imu.solver import calibrate_imu_camera

__all__ = ["BENT", "CONDITIONS", "SEED", "Condition", "imu_errors", "imu_md", "run_imu", "run_imu_trial"]

#: first seed of the trials
SEED = 700_000
#: the bent board's sag (m, mrcal's ``calobject_warp``): 2 mm and 1 mm at the centre of the 0.48 x 0.40 m board
BENT = (-0.002, 0.001)


class Condition(NamedTuple):
    """One condition of the bench: the recording and how it is fitted."""

    cameras: int = 1
    noise_factor: float = 1.0  #: the stated noise over the true
    line_delay: float = 0.0  #: a rolling shutter's row delay (s)
    rig_held: bool = False  #: the rig's extrinsics given and held
    imu_errors: bool = False  #: the IMU has intrinsic errors (:func:`imu_errors`)
    imu_model: ImuModel = ImuModel.CALIBRATED  #: the model fitted
    same_as: str | None = None  #: the condition whose recordings (seeds) this one fits another way
    board_warp: tuple[float, float] | None = None  #: the rendered board's sag (m; None: flat)
    board_flatness: bool = False  #: the sag fitted and judged (the command line's default)


CONDITIONS = {"given": Condition(), "noise x10": Condition(noise_factor=10.0), "noise /10": Condition(noise_factor=0.1),
              "stereo": Condition(cameras=2), "rolling shutter": Condition(line_delay=3e-5),
              "stereo, rig held": Condition(cameras=2, rig_held=True, same_as="stereo"),
              "IMU errors, ideal model": Condition(imu_errors=True),
              "IMU errors, scale-misalignment": Condition(imu_errors=True, imu_model=ImuModel.SCALE_MISALIGNMENT,
                                                          same_as="IMU errors, ideal model"),
              "given, sag judged": Condition(board_flatness=True, same_as="given"),
              "bent board, flat": Condition(board_warp=BENT),
              "bent board, sag judged": Condition(board_warp=BENT, board_flatness=True, same_as="bent board, flat")}


def imu_errors(seed: int) -> ImuIntrinsics:
    """A MEMS IMU's intrinsic errors drawn from ``seed`` (the module doc's ranges).

    Example:
        >>> imu = imu_errors(1)
        >>> bool((imu.gyro_matrix.diagonal() - 1).abs().max() <= 0.015 + 0.005)
        True
    """
    g = torch.Generator().manual_seed(int(seed))
    f64 = torch.float64

    def uniform(*shape, scale):
        return (torch.rand(*shape, generator=g, dtype=f64) * 2 - 1) * scale

    eye = torch.eye(3, dtype=f64)
    scale_g, scale_a = torch.diag(uniform(3, scale=0.015)), torch.diag(uniform(3, scale=0.015))
    misalign_g = torch.triu(uniform(3, 3, scale=0.005), 1)
    misalign_a = torch.triu(uniform(3, 3, scale=0.005), 1)
    gyro = (eye + scale_g + misalign_g) @ exp_so3(uniform(3, scale=0.005))
    return ImuIntrinsics(gyro, eye + scale_a + misalign_a, uniform(3, 3, scale=3e-4))


def run_imu_trial(seed: int, seconds: float, condition: Condition = Condition()) -> dict:
    """One rendered recording solved; its errors against the truth (a JSON-able dict)."""
    cameras, line_delay = condition.cameras, condition.line_delay
    rec = visual_inertial_recording(duration=seconds, seed=seed, num_cameras=cameras, line_delay=line_delay,
                                    imu_intrinsics=imu_errors(seed + 1) if condition.imu_errors else None,
                                    board_warp=condition.board_warp)
    data = ImuCameraData.from_corners(rec.imu_times, rec.gyro, rec.accel, rec.cameras, rec.object_points,
                                      rec.frame_times, rec.corners)
    rig = rec.T_cam_imu @ torch.linalg.inv(rec.T_cam_imu[0]) if condition.rig_held else None
    res = calibrate_imu_camera(data, noise=rec.noise.scaled(condition.noise_factor), rolling_shutter=line_delay > 0,
                               rig=rig, imu_model=condition.imu_model, board_flatness=condition.board_flatness)
    imu = {}
    if res.board_flatness is not None:
        truth = torch.tensor(condition.board_warp or (0.0, 0.0), dtype=torch.float64)
        fitted = torch.tensor(res.board_flatness["warp_m"], dtype=torch.float64)
        used = res.board_warp if res.board_warp is not None else torch.zeros(2, dtype=torch.float64)
        imu["sag"] = {"kept": res.board_flatness["kept"], "fitted_err_mm": 1000 * float((fitted - truth).abs().max()),
                      "used_err_mm": 1000 * float((used - truth).abs().max()),
                      "heldout_px": res.board_flatness["heldout_median_px"]}
    if res.imu_intrinsics is not None:
        est, truth = res.imu_intrinsics, rec.imu_intrinsics
        imu = {"imu_matrix_err_pct": 100 * max(float((est.gyro_matrix - truth.gyro_matrix).abs().max()),
                                               float((est.accel_matrix - truth.accel_matrix).abs().max())),
               "g_sensitivity_err": float((est.g_sensitivity - truth.g_sensitivity).abs().max())}
    cams = []
    for c in range(cameras):
        w = log_so3(res.T_cam_imu[c, :3, :3] @ rec.T_cam_imu[c, :3, :3].T)
        dt = res.T_cam_imu[c, :3, 3] - rec.T_cam_imu[c, :3, 3]
        ds = float(res.timeshift_cam_imu[c] - rec.shift[c])
        sr = res.rotation_std_deg[c] * math.pi / 180
        within = ((w.abs() <= sr).sum() + (dt.abs() <= res.translation_std[c]).sum()
                  + int(abs(ds) <= float(res.timeshift_std[c])))
        cams.append({"r_deg": float(w.norm()) * 180 / math.pi, "t_mm": 1000 * float(dt.norm()), "shift_ms": 1000 * ds,
                     "r_std_deg": float(res.rotation_std_deg[c].norm()),
                     "t_std_mm": 1000 * float(res.translation_std[c].norm()),
                     "shift_std_ms": 1000 * float(res.timeshift_std[c]), "within": int(within), "components": 7,
                     **({"line_delay_err_us": 1e6 * float(res.line_delay[c] - line_delay)}
                        if res.line_delay is not None else {})})
    return {"seed": seed, "seconds": seconds, "cameras": cams, "fit_s": res.seconds, "verdict": res.verdict, **imu,
            "iterations": res.iterations, "true_shift_ms": [1000 * float(s) for s in rec.shift],
            "gyro_noise_ratio": res.noise_measured.gyroscope_noise_density / rec.noise.gyroscope_noise_density,
            "accel_noise_ratio": res.noise_measured.accelerometer_noise_density / rec.noise.accelerometer_noise_density}


def _summary(rows: list[dict]) -> dict:
    per_cam = [c for r in rows for c in r["cameras"]]

    def med(key):
        return statistics.median(abs(c[key]) for c in per_cam)

    return {"trials": len(rows), "r_deg_median": med("r_deg"), "t_mm_median": med("t_mm"),
            "shift_ms_median": med("shift_ms"), "r_deg_max": max(c["r_deg"] for c in per_cam),
            "t_mm_max": max(c["t_mm"] for c in per_cam), "shift_ms_max": max(abs(c["shift_ms"]) for c in per_cam),
            "coverage": sum(c["within"] for c in per_cam) / sum(c["components"] for c in per_cam),
            "fit_s_median": statistics.median(r["fit_s"] for r in rows), "fit_s_max": max(r["fit_s"] for r in rows),
            "verdicts": {v: sum(r["verdict"].split(":")[0] == v for r in rows)
                         for v in sorted({r["verdict"].split(":")[0] for r in rows})},
            **({"line_delay_err_us_median": med("line_delay_err_us")} if "line_delay_err_us" in per_cam[0] else {}),
            **({"imu_matrix_err_pct_median": statistics.median(r["imu_matrix_err_pct"] for r in rows),
                "g_sensitivity_err_median": statistics.median(r["g_sensitivity_err"] for r in rows)}
               if "imu_matrix_err_pct" in rows[0] else {}),
            **({"sag_kept": sum(r["sag"]["kept"] for r in rows),
                "sag_fitted_err_mm_median": statistics.median(r["sag"]["fitted_err_mm"] for r in rows),
                "sag_used_err_mm_median": statistics.median(r["sag"]["used_err_mm"] for r in rows)}
               if "sag" in rows[0] else {})}


def run_imu(cfg=None, log=print) -> dict:
    """Run the benchmark (``cfg.imu_trials`` recordings of ``cfg.imu_seconds`` s per condition). Returns a JSON-able
    dict."""
    trials = int(getattr(cfg, "imu_trials", 10))
    seconds = float(getattr(cfg, "imu_seconds", 60.0))
    conditions = tuple(getattr(cfg, "imu_conditions", tuple(CONDITIONS)))
    out: dict = {"trials": trials, "recording_s": seconds, "seed": SEED, "conditions": {}}
    for name in conditions:
        # the seeds are the condition's place in CONDITIONS (or the place of the one whose recordings it fits another
        # way): a condition's recordings do not depend on which others run
        k = list(CONDITIONS).index(CONDITIONS[name].same_as or name)
        rows = []
        for t in range(trials):
            rows.append(run_imu_trial(SEED + 1000 * k + t, seconds, CONDITIONS[name]))
            c = rows[-1]["cameras"][0]
            log(f"[imu] {name} trial {t + 1}/{trials}: {c['r_deg']:.4f} deg, {c['t_mm']:.3f} mm, "
                f"{c['shift_ms']:+.4f} ms in {rows[-1]['fit_s']:.1f} s")
        out["conditions"][name] = {"rows": rows, "summary": _summary(rows)}
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    out["threads"] = torch.get_num_threads()
    return out


def imu_md(sec: dict) -> list[str]:
    """Markdown of :func:`run_imu`'s result."""
    if "conditions" not in sec:
        return [f"Not run: {sec.get('error') or sec.get('skipped', '')}"]
    lines = [(f"{sec['trials']} rendered recordings of {sec['recording_s']:g} s per condition (a camera with an IMU, "
             "swung by hand before a board; 20 fps global shutter, 0.2 px corners; IMU 200 Hz with EuRoC's noise and "
             "bias walk; time offsets -30..+30 ms). Errors of T_cam_imu and the time offset against the truth, over "
             "every camera; coverage: the error's components within their 1-sigma (68 % expected)."), "",
             ("| condition | rotation deg median / max | translation mm median / max | time offset ms median / max | "
             "1-sigma coverage | fit s median / max | verdicts |"), "|---|---|---|---|---|---|---|"]
    for name, c in sec["conditions"].items():
        s = c["summary"]
        verdicts = ", ".join(f"{v} {n}" for v, n in s["verdicts"].items())
        lines.append(f"| {name} | {s['r_deg_median']:.4f} / {s['r_deg_max']:.4f} | {s['t_mm_median']:.3f} / "
                     f"{s['t_mm_max']:.3f} | {s['shift_ms_median']:.4f} / {s['shift_ms_max']:.4f} | "
                     f"{100 * s['coverage']:.0f} % | {s['fit_s_median']:.1f} / {s['fit_s_max']:.1f} | {verdicts} |")
    delays = [f"{name}: {c['summary']['line_delay_err_us_median']:.3f} us" for name, c in sec["conditions"].items()
              if "line_delay_err_us_median" in c["summary"]]
    if delays:
        lines += ["", "Row delay error (median, the truth 30 us): " + ", ".join(delays) + "."]
    imu = [f"{name}: scale and misalignment {c['summary']['imu_matrix_err_pct_median']:.3f} %, g-sensitivity "
           f"{c['summary']['g_sensitivity_err_median']:.2e} rad/s per m/s^2" for name, c in sec["conditions"].items()
           if "imu_matrix_err_pct_median" in c["summary"]]
    if imu:
        lines += ["", "The IMU's intrinsics, largest error of a matrix entry (median): " + "; ".join(imu) + "."]
    sags = [f"{name}: kept in {c['summary']['sag_kept']} of {c['summary']['trials']}, the fitted sag "
            f"{c['summary']['sag_fitted_err_mm_median']:.3f} mm from the truth (median), the board used "
            f"{c['summary']['sag_used_err_mm_median']:.3f} mm" for name, c in sec["conditions"].items()
            if "sag_kept" in c["summary"]]
    if sags:
        lines += ["", "The board's sag (largest coefficient's error): " + "; ".join(sags) + "."]
    lines += ["", (f"Peak memory of the bench process after the section: {sec['peak_rss_mb']:.0f} MB "
              f"({sec['threads']} torch threads)."), ""]
    return lines
