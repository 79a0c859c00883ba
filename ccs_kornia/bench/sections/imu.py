r"""Camera-IMU benchmark: the fit against the truth on rendered visual-inertial recordings.

**Rendered recordings** (:func:`~ccs_kornia.data.recordings.visual_inertial.visual_inertial_recording`): a camera
(EuRoC's cam0: 752x480, radial-tangential) with an IMU at a random pose on it (any rotation, up to 10 cm away),
swung by hand in front of a 7x6-point board for ``imu_seconds`` s (smooth analytic motion, not a spline: 0.15-1.6 Hz,
about 0.5 rad about each axis and 0.2 m along each), global shutter at 20 fps, corners with 0.2 px noise; an IMU at
200 Hz with EuRoC's ADIS16448 noise and bias random walk; a time offset drawn in -30 .. +30 ms. Seeds start at
:data:`SEED` (the tests and doctests use seeds below 1000).

Conditions: the IMU's noise given as it is (``given``), given 10x too large (``noise x10``) and 10x too small
(``noise /10``), as users' ``imu.yaml`` files are (Kalibr's users report values 10-20x off); a stereo rig
(``stereo``, two cameras 11 cm apart, the noise given); a rolling-shutter camera (``rolling shutter``: rows read
30 us apart, 14 ms for the frame; fitted with its row delay).

Per trial: each camera's ``T_cam_imu`` error (rotation degrees, translation mm) and time-offset error (ms); the
honesty of the 1-sigma: the fraction of the error's components (3 rotation, 3 translation, 1 time offset per camera)
within their 1-sigma (68 % for an honest Gaussian sigma); the fit's wall time; the process's peak memory after the
section (an upper bound of the fit's).
"""

from __future__ import annotations

import math
import resource
import statistics

import torch

from ccs_kornia.data.recordings.visual_inertial import visual_inertial_recording
from ccs_kornia.geometry.so3 import log_so3
from ccs_kornia.modules.imu.problem import ImuCameraData
from ccs_kornia.modules.imu.solver import calibrate_imu_camera

__all__ = ["CONDITIONS", "SEED", "imu_md", "run_imu", "run_imu_trial"]

#: first seed of the trials
SEED = 700_000
#: condition -> (cameras, factor of the stated noise, a rolling shutter's row delay in s)
CONDITIONS = {"given": (1, 1.0, 0.0), "noise x10": (1, 10.0, 0.0), "noise /10": (1, 0.1, 0.0), "stereo": (2, 1.0, 0.0),
              "rolling shutter": (1, 1.0, 3e-5)}


def run_imu_trial(seed: int, seconds: float, cameras: int = 1, noise_factor: float = 1.0,
                  line_delay: float = 0.0) -> dict:
    """One rendered recording solved; its errors against the truth (a JSON-able dict)."""
    rec = visual_inertial_recording(duration=seconds, seed=seed, num_cameras=cameras, line_delay=line_delay)
    data = ImuCameraData.from_corners(rec.imu_times, rec.gyro, rec.accel, rec.cameras, rec.object_points,
                                      rec.frame_times, rec.corners)
    res = calibrate_imu_camera(data, noise=rec.noise.scaled(noise_factor), rolling_shutter=line_delay > 0)
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
    return {"seed": seed, "seconds": seconds, "cameras": cams, "fit_s": res.seconds, "verdict": res.verdict,
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
            **({"line_delay_err_us_median": med("line_delay_err_us")} if "line_delay_err_us" in per_cam[0] else {})}


def run_imu(cfg=None, log=print) -> dict:
    """Run the benchmark (``cfg.imu_trials`` recordings of ``cfg.imu_seconds`` s per condition). Returns a JSON-able
    dict."""
    trials = int(getattr(cfg, "imu_trials", 10))
    seconds = float(getattr(cfg, "imu_seconds", 60.0))
    conditions = tuple(getattr(cfg, "imu_conditions", tuple(CONDITIONS)))
    out: dict = {"trials": trials, "recording_s": seconds, "seed": SEED, "conditions": {}}
    for k, name in enumerate(conditions):
        cameras, factor, delay = CONDITIONS[name]
        rows = []
        for t in range(trials):
            rows.append(run_imu_trial(SEED + 1000 * k + t, seconds, cameras, factor, delay))
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
    lines += ["", (f"Peak memory of the bench process after the section: {sec['peak_rss_mb']:.0f} MB "
              f"({sec['threads']} torch threads)."), ""]
    return lines
