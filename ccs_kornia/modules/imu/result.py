r"""The camera-IMU result and its verdict.

:class:`ImuCameraResult` holds one recording's answer for C cameras. Its 1-sigma come from the fit's covariance
(the spline, biases and gravity marginalised), with each sensor's noise as the recording shows it (variance components:
the stated noise densities are rescaled to the residuals, :mod:`~ccs_kornia.modules.imu.solver`). Rotations are
left perturbations in the camera's frame (``R_cam_imu <- exp(w) R_cam_imu``).

The verdict (:func:`imu_camera_verdict`) reads what a user acts on: each camera's 1-sigma in rotation, translation
and time offset, naming the camera axis along which the motion was too weak (the weakest direction of the
covariance) and how to move; the time offset's search (an offset at its edge, a weak correlation); residuals that do
not look like the stated noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.imu_intrinsics import ImuIntrinsics
from ccs_kornia.geometry.imu_noise import ImuNoise

__all__ = ["ImuCameraResult", "ImuVerdictThresholds", "imu_camera_verdict"]

#: the camera's axes in words (x right, y down, z forward)
_AXES = ("X (left-right)", "Y (up-down)", "Z (forward-back)")
_ROTATIONS = ("X (tilting it up and down)", "Y (panning it left and right)", "Z (rolling it about the lens)")


@dataclass
class ImuVerdictThresholds:
    """Limits of the verdict on each camera's 1-sigma: rotation (degrees), translation (m), time offset (s); the ratio
    of a sensor's residuals to its stated noise beyond which the stated noise is called off; the least correlation
    of the angular speeds; the corners' RMS (px) beyond which a global-shutter fit is asked whether the camera has a
    rolling shutter."""

    good_rotation_deg: float = 0.05
    usable_rotation_deg: float = 0.3
    good_translation: float = 0.002
    usable_translation: float = 0.01
    good_shift: float = 2e-4
    usable_shift: float = 2e-3
    noise_ratio: float = 3.0
    min_correlation: float = 0.5
    max_pixel_rms: float = 1.0
    #: an ideal IMU's residual following its reading by more than this (0.1 %) ...
    imu_scale: float = 1e-3
    #: ... and this many standard errors: its intrinsics are asked for (``--imu-model scale-misalignment``)
    imu_scale_sigmas: float = 6.0


@dataclass
class ImuCameraResult:
    """Camera-IMU calibration of one recording with C cameras.

    ``T_cam_imu`` maps IMU-frame points into the camera's frame; a frame stamped ``t_cam`` by a camera was seen at IMU
    time ``t_cam + timeshift_cam_imu`` (Kalibr's conventions).
    """

    T_cam_imu: torch.Tensor  #: (C, 4, 4)
    timeshift_cam_imu: torch.Tensor  #: (C,) s
    rotation_std_deg: torch.Tensor  #: (C, 3) about the camera's axes
    translation_std: torch.Tensor  #: (C, 3) m, along the camera's axes
    timeshift_std: torch.Tensor  #: (C,) s
    covariance: torch.Tensor  #: (G, G) of the global unknowns (per camera w, t, shift; gravity's 2; the IMU's; the sag's)
    gravity: torch.Tensor  #: (3,) m/s^2 in the board's frame
    gyro_bias: torch.Tensor  #: (M, 3) the bias spline's control points, rad/s
    accel_bias: torch.Tensor  #: (M, 3) m/s^2
    gyro_rms: float  #: rad/s, the gyroscope's residuals
    accel_rms: float  #: m/s^2
    pixel_rms: torch.Tensor  #: (C,) px
    noise_stated: ImuNoise  #: the noise the fit started from (given, or the default)
    noise_measured: ImuNoise  #: the white noise densities the residuals show (random walks as stated)
    pixel_sigma: float  #: px, the corners' noise the residuals show
    noise_given: bool  #: whether the stated noise was the user's
    alignment_shifts: torch.Tensor  #: (S,) s, the time offsets the rate alignment tried
    alignment_correlation: torch.Tensor  #: (C, S) the angular speeds' correlation at each
    alignment_shift: torch.Tensor  #: (C,) s, the alignment's time offset (the fit's start)
    max_shift: float  #: s, the search's half-width (about the clocks' offset when they were aligned)
    frames_used: torch.Tensor  #: (C,) int64
    knot_spacing: float  #: s
    iterations: int
    status: int  #: :class:`~ccs_kornia.modules.calibration.schur_lm.LMStatus`
    seconds: float  #: the fit's wall time
    line_delay: torch.Tensor | None = None  #: (C,) s per row of a rolling-shutter camera (None: global shutter)
    line_delay_std: torch.Tensor | None = None  #: (C,) s
    #: (C,) s, each camera's clock offset found over the whole recordings before the search (clocks aligned), or None
    clock_offset: torch.Tensor | None = None
    rig_held: bool = False  #: the cameras' poses in camera 0's frame were held (a rig's extrinsics), not fitted
    cameras: Camera | None = None  #: the cameras the fit used: as given, or refined (``intrinsics_std`` set)
    intrinsics_std: torch.Tensor | None = None  #: (C, P) the refined parameters' 1-sigma (None: held)
    #: the IMU's intrinsics when estimated (``--imu-model scale-misalignment``), else None (an ideal IMU)
    imu_intrinsics: ImuIntrinsics | None = None
    imu_intrinsics_std: torch.Tensor | None = None  #: (24,) T_g by rows, T_a's upper triangle, A_g by rows
    #: with the IMU taken as ideal: per sensor ("gyroscope", "accelerometer") how far its residuals follow its
    #: readings, ``(largest entry of E, its ratio to its standard error)`` (:mod:`~.intrinsics_evidence`)
    residual_scale: dict = field(default_factory=dict)
    #: (2,) the board's sag where the fit kept it (mrcal's ``calobject_warp``, the board's units;
    #: :mod:`~ccs_kornia.modules.imu.imu_flatness`), else None (a flat board)
    board_warp: torch.Tensor | None = None
    board_warp_std: torch.Tensor | None = None  #: (2,) its 1-sigma
    #: where the sag was judged, what was found
    #: (:func:`~ccs_kornia.modules.calibration.board_flatness.board_warp_record`), else None
    board_flatness: dict | None = None
    verdict: str = ""
    verdict_reasons: list[str] = field(default_factory=list)
    spline: dict = field(default_factory=dict, repr=False)  #: t0, dt, R, p: the IMU's trajectory (for reports)
    #: the fit's residuals (for reports): ``imu_times`` (N,), ``gyro`` (N, 3), ``accel`` (N, 3) (prediction minus
    #: measurement), ``frame_times`` (F,), ``frame_camera`` (F,), ``corners`` (F, P, 2) px, ``seen`` (F, P)
    residuals: dict = field(default_factory=dict, repr=False)


def _ratio(measured: float, stated: float) -> float:
    return measured / stated if stated > 0 else float("inf")


def imu_camera_verdict(result: ImuCameraResult, thresholds: ImuVerdictThresholds | None = None) -> tuple[str, list[str]]:
    """``("good" | "usable" | "not reliable: <advice>", reasons)`` of a result (see the module doc).

    Example:
        >>> from ccs_kornia.data.recordings.visual_inertial import visual_inertial_recording
        >>> from ccs_kornia.modules.imu.problem import ImuCameraData
        >>> from ccs_kornia.modules.imu.solver import calibrate_imu_camera
        >>> r = visual_inertial_recording(duration=8.0, seed=3)
        >>> res = calibrate_imu_camera(ImuCameraData.from_corners(r.imu_times, r.gyro, r.accel, r.cameras,
        ...                                                       r.object_points, r.frame_times, r.corners))
        >>> imu_camera_verdict(res)[0]
        'good'
    """
    t = thresholds or ImuVerdictThresholds()
    bad, weak, advice = [], [], []
    C = result.T_cam_imu.shape[0]
    for c in range(C):
        name = f"camera {c}: " if C > 1 else ""
        rot = result.rotation_std_deg[c]
        tr = result.translation_std[c]
        r_norm, t_norm = float(rot.norm()), float(tr.norm())
        s = float(result.timeshift_std[c])
        if not (math.isfinite(r_norm) and math.isfinite(t_norm) and math.isfinite(s)):
            bad.append(f"{name}the motion does not determine where the IMU sits")
            advice.append("move the camera along and rotate it about all three of its axes, the board in view")
            continue
        if r_norm > t.usable_rotation_deg:
            axis = _ROTATIONS[int(rot.argmax())]
            bad.append(f"{name}rotation 1-sigma {r_norm:.3f} deg")
            advice.append(f"rotate the camera more about its {axis}")
        elif r_norm > t.good_rotation_deg:
            weak.append(f"{name}rotation 1-sigma {r_norm:.3f} deg (most about the camera's {_ROTATIONS[int(rot.argmax())]})")
        if t_norm > t.usable_translation:
            axis = _AXES[int(tr.argmax())]
            bad.append(f"{name}translation 1-sigma {1000 * t_norm:.1f} mm")
            advice.append(f"accelerate the camera more along its {axis} axis (short, brisk moves) and rotate it more")
        elif t_norm > t.good_translation:
            weak.append(f"{name}translation 1-sigma {1000 * t_norm:.2f} mm (most along the camera's "
                        f"{_AXES[int(tr.argmax())]} axis)")
        if s > t.usable_shift:
            bad.append(f"{name}time offset 1-sigma {1000 * s:.2f} ms")
            advice.append("rotate the camera faster, back and forth, the board in view")
        elif s > t.good_shift:
            weak.append(f"{name}time offset 1-sigma {1000 * s:.3f} ms")
        px = float(result.pixel_rms[c])
        if px > t.max_pixel_rms:
            causes = ([] if result.line_delay is not None else ["a rolling-shutter camera (--rolling-shutter)"]) + \
                ([] if result.intrinsics_std is not None else ["a camera calibration that does not fit these images "
                                                               "(--refine-intrinsics)"])
            weak.append(f"{name}the corners fit to {px:.2f} px RMS" + (f": {' or '.join(causes)}?" if causes else ""))
        corr = float(result.alignment_correlation[c].max())
        if corr < t.min_correlation:
            weak.append(f"{name}the camera's and the gyroscope's angular speeds agree weakly (correlation {corr:.2f})")
    for sensor, (e, z) in result.residual_scale.items():
        if e > t.imu_scale and z > t.imu_scale_sigmas:
            weak.append(f"the {sensor}'s residuals follow its readings ({100 * e:.2f} % of them, {z:.0f} sigma): scale "
                        "or axis errors of the IMU: fit them (--imu-model scale-misalignment)")
    stated, measured = result.noise_stated, result.noise_measured
    g = _ratio(measured.gyroscope_noise_density, stated.gyroscope_noise_density)
    a = _ratio(measured.accelerometer_noise_density, stated.accelerometer_noise_density)
    for what, r in (("gyroscope", g), ("accelerometer", a)):
        if result.noise_given and (r > t.noise_ratio or r < 1 / t.noise_ratio):
            weak.append(f"the {what}'s residuals are {r:.2g}x its stated noise density: imu.yaml's value is off "
                        "(the fit used the measured one)")
    if bad:
        return "not reliable: " + "; ".join(dict.fromkeys(advice)), bad + weak
    return ("usable" if weak else "good"), weak
