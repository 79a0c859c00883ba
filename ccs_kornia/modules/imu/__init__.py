"""Camera-IMU calibration: where an IMU sits on a camera (or rig) and the time offset between their clocks, from one
recording (docs/imu.md).

:class:`ImuCameraSolver` / :func:`calibrate_imu_camera` (:mod:`.solver`): the start from the angular rates
(:mod:`.initial`), the joint fit of a continuous-time trajectory to every gyroscope, accelerometer and corner
measurement (:mod:`.problem`), the result and its verdict (:mod:`.result`), the board's sag judged on held-out frames
(:mod:`.imu_flatness`); the IMU's noise read off a still log's
Allan deviation (:mod:`.allan`).

Names are imported lazily (PEP 562): importing this package loads none of its modules.
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "ImuCameraSolver": "ccs_kornia.modules.imu.solver",
    "calibrate_imu_camera": "ccs_kornia.modules.imu.solver",
    "ImuCameraData": "ccs_kornia.modules.imu.problem",
    "ImuCameraProblem": "ccs_kornia.modules.imu.problem",
    "ImuCameraResult": "ccs_kornia.modules.imu.result",
    "ImuVerdictThresholds": "ccs_kornia.modules.imu.result",
    "imu_camera_verdict": "ccs_kornia.modules.imu.result",
    "ImuBoardWarpChoice": "ccs_kornia.modules.imu.imu_flatness",
    "choose_imu_board_warp": "ccs_kornia.modules.imu.imu_flatness",
    "RateAlignment": "ccs_kornia.modules.imu.initial",
    "align_rates": "ccs_kornia.modules.imu.initial",
    "AllanNoise": "ccs_kornia.modules.imu.allan",
    "allan_deviation": "ccs_kornia.modules.imu.allan",
    "allan_taus": "ccs_kornia.modules.imu.allan",
    "noise_from_allan": "ccs_kornia.modules.imu.allan",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
