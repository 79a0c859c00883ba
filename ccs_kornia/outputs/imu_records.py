"""``imu_cam.json``: the camera-IMU calibration as the command line writes it (DESIGN.md §4).

Per camera ``T_cam_imu`` (4x4, ``x_cam = T_cam_imu x_imu``) and ``timeshift_cam_imu`` (s, ``t_imu = t_cam + shift``)
with their 1-sigma; gravity in the board's frame; the biases' range; each sensor's residual RMS beside the noise it
was stated and measured to have; the time-offset search; the board's sag where it was judged (``board_flatness``, as
every fit of a board writes it); the verdict.
"""

from __future__ import annotations

import math
from typing import Any

from ccs_kornia.geometry.imu_intrinsics import UPPER
from ccs_kornia.geometry.imu_noise import ImuNoise
from ccs_kornia.modules.imu.result import ImuCameraResult
from ccs_kornia.outputs.calibration_file import camera_record_fields

__all__ = ["imu_camera_record", "noise_record"]


def _r(x: float, digits: int = 9) -> float | None:
    x = float(x)
    return round(x, digits) if math.isfinite(x) else None


def noise_record(noise: ImuNoise) -> dict[str, float]:
    """Kalibr's four noise values and the rate."""
    return {"accelerometer_noise_density": _r(noise.accelerometer_noise_density, 12),
            "accelerometer_random_walk": _r(noise.accelerometer_random_walk, 12),
            "gyroscope_noise_density": _r(noise.gyroscope_noise_density, 12),
            "gyroscope_random_walk": _r(noise.gyroscope_random_walk, 12),
            "update_rate": _r(noise.update_rate, 6)}


def _intrinsics_std(sd) -> dict[str, Any]:
    """A refined camera's 1-sigma: focal lengths and centre (px), then the lens coefficients in the model's order."""
    v = [_r(x, 9) for x in sd.tolist()]
    return {"fx": v[0], "fy": v[1], "cx": v[2], "cy": v[3], "distortion": v[4:]}


def _imu_intrinsics_record(result: ImuCameraResult) -> dict[str, Any]:
    """The IMU's estimated intrinsics (geometry.imu_intrinsics: w_m = T_g w + A_g f + b_g, a_m = T_a f + b_a) and
    their 1-sigma."""
    imu, sd = result.imu_intrinsics, result.imu_intrinsics_std.tolist()
    upper = [[0.0] * 3 for _ in range(3)]
    for k, (i, j) in enumerate(UPPER):
        upper[i][j] = _r(sd[9 + k], 9)

    def rows(m) -> list[list[float]]:
        return [[_r(v, 9) for v in row] for row in m.tolist()]

    return {"model": "scale-misalignment",
            "convention": "gyro = T_g w + A_g f + b_g; accel = T_a f + b_a (w, f: true rate and specific force in the "
                          "IMU's frame, the accelerometer's axes)",
            "T_g": rows(imu.gyro_matrix), "T_a": rows(imu.accel_matrix), "A_g": rows(imu.g_sensitivity),
            "T_g_std": [[_r(v, 9) for v in sd[3 * i:3 * i + 3]] for i in range(3)], "T_a_std": upper,
            "A_g_std": [[_r(v, 9) for v in sd[15 + 3 * i:18 + 3 * i]] for i in range(3)]}


def imu_camera_record(result: ImuCameraResult, names: list[str], extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """The JSON record of a result (``names``: the cameras', in order)."""
    cams = []
    for c, name in enumerate(names):
        T = result.T_cam_imu[c]
        cams.append({
            "name": name,
            "T_cam_imu": [[_r(v) for v in row] for row in T.tolist()],
            "timeshift_cam_imu": _r(result.timeshift_cam_imu[c]),
            "rotation_std_deg": [_r(v, 6) for v in result.rotation_std_deg[c].tolist()],
            "translation_std_m": [_r(v, 9) for v in result.translation_std[c].tolist()],
            "timeshift_std_s": _r(result.timeshift_std[c], 9),
            **({"line_delay_s": _r(result.line_delay[c], 12), "line_delay_std_s": _r(result.line_delay_std[c], 12)}
               if result.line_delay is not None else {}),
            **({"camera_refined": {**camera_record_fields(result.cameras[c]),
                                   "std": _intrinsics_std(result.intrinsics_std[c])}}
               if result.intrinsics_std is not None else {}),
            "frames_used": int(result.frames_used[c]),
            "pixel_rms": _r(result.pixel_rms[c], 4),
            "time_offset_search": {
                **({"clock_offset_s": _r(result.clock_offset[c])} if result.clock_offset is not None else {}),
                "start_s": _r(result.alignment_shift[c]),
                "max_shift_s": result.max_shift,
                "peak_correlation": _r(result.alignment_correlation[c].max(), 4),
            },
        })
    stated, measured = result.noise_stated, result.noise_measured
    return {
        "cameras": cams,
        "convention": "x_cam = T_cam_imu x_imu; t_imu = t_cam + timeshift_cam_imu",
        "rig_extrinsics": "held (the cameras' poses in camera 0's frame as calibrated)" if result.rig_held else "fitted",
        "gravity": [_r(v, 6) for v in result.gravity.tolist()],
        "gravity_frame": "the board's",
        "biases": {
            "gyroscope_min": [_r(v, 6) for v in result.gyro_bias.amin(0).tolist()],
            "gyroscope_max": [_r(v, 6) for v in result.gyro_bias.amax(0).tolist()],
            "accelerometer_min": [_r(v, 6) for v in result.accel_bias.amin(0).tolist()],
            "accelerometer_max": [_r(v, 6) for v in result.accel_bias.amax(0).tolist()],
        },
        "residuals": {
            "gyroscope_rms": _r(result.gyro_rms, 9),
            "gyroscope_sample_sigma_stated": _r(stated.gyroscope_noise_density * math.sqrt(measured.update_rate), 9),
            "accelerometer_rms": _r(result.accel_rms, 9),
            "accelerometer_sample_sigma_stated": _r(stated.accelerometer_noise_density * math.sqrt(measured.update_rate), 9),
            "pixel_sigma": _r(result.pixel_sigma, 4),
            **{f"{sensor}_follows_readings": {"largest": _r(e, 6), "sigmas": _r(z, 2)}
               for sensor, (e, z) in result.residual_scale.items()},
        },
        "noise": {"given": result.noise_given, "stated": noise_record(stated), "measured": noise_record(measured)},
        "fit": {"knot_spacing_s": result.knot_spacing, "iterations": result.iterations, "status": result.status,
                "seconds": _r(result.seconds, 3)},
        **({"imu_intrinsics": _imu_intrinsics_record(result)} if result.imu_intrinsics is not None else {}),
        # the board's sag, and whether held-out frames kept it
        **({"board_flatness": result.board_flatness} if result.board_flatness is not None else {}),
        "verdict": result.verdict,
        "verdict_reasons": list(result.verdict_reasons),
        **(extra or {}),
    }
