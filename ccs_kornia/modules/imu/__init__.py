"""The IMU beside the cameras: its noise read off a still log's Allan deviation (:mod:`.allan`).

Names are imported lazily (PEP 562): importing this package loads none of its modules.
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "AllanNoise": "ccs_kornia.modules.imu.allan",
    "allan_deviation": "ccs_kornia.modules.imu.allan",
    "allan_taus": "ccs_kornia.modules.imu.allan",
    "noise_from_allan": "ccs_kornia.modules.imu.allan",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
