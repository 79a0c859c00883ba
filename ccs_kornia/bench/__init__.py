"""Benchmarks of ccs_kornia against OpenCV and libcbdetect, side by side in one run (DESIGN.md §6).

``python -m ccs_kornia bench [--quick] [--out DIR] [--sections ...] [--markdown docs/benchmarks.md]``
(also ``python -m ccs_kornia.bench``) writes ``results.json``, ``report.md`` and the RMS box plot to
``--out``. Sections (paper tables in brackets): ``corners`` (III), ``calibration`` (I), ``real`` (II and the
RPE box plot), ``distortion`` (IV), ``speed``, ``wild`` (detection in the wild), ``fisheye`` (fisheye lenses),
``rig`` (camera rigs), ``markers`` (ChArUco and AprilGrid boards).
Synthetic scenes use seeds from :data:`ccs_kornia.data.datamodules.datamodule.BENCH_SEED_BASE` upwards, which training never
uses.

Example:
    >>> from ccs_kornia.bench import BenchConfig, run_bench
    >>> results = run_bench(BenchConfig.tiny(sections=("corners",)), "/tmp/bench")  # doctest: +SKIP
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "BenchConfig": "ccs_kornia.bench.config",
    "METHODS": "ccs_kornia.bench.config",
    "SECTIONS": "ccs_kornia.bench.config",
    "run_bench": "ccs_kornia.bench.runner",
}

__all__ = ["BenchConfig", "run_bench", "SECTIONS", "METHODS"]
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
