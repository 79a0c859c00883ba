"""Run the benchmark sections and write JSON, markdown and the box plot."""

from __future__ import annotations

import importlib
import time
import traceback
from datetime import datetime, timezone
from pathlib import Path

from ccs_kornia.bench.config import SECTIONS, BenchConfig
from ccs_kornia.bench.methods.methods import make_methods
from ccs_kornia.bench.report.report import (
    draw_boxplot,
    machine_info,
    render_markdown,
    write_markdown,
)

__all__ = ["run_bench"]


def run_bench(
    cfg: BenchConfig,
    out_dir: str | Path,
    command: str = "python -m ccs_kornia bench",
    markdown: str | Path | None = None,
    log=print,
) -> dict:
    """Run the configured sections; write ``results.json``, ``report.md`` (and ``real_rms_boxplot.png``) to
    ``out_dir`` and, if given, the markdown report to ``markdown`` as well.

    A section that raises is recorded as ``{"error": ...}`` and the others still run.

    Returns:
        The results dict (``meta`` and ``sections``), as written to ``results.json``.
    """
    from ccs_kornia.io.files import write_json
    for s in cfg.sections:
        if s not in SECTIONS:
            raise ValueError(f"Unknown section {s!r}; expected some of {SECTIONS}.")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    started = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    methods = make_methods(cfg.methods, cfg.learned_batch)
    for m in methods.values():
        if not m.available:
            log(f"[bench] {m.label}: {m.reason} — skipped")
    meta = {
        "command": command,
        "started": started,
        "machine": machine_info(),
        "config": cfg.to_dict(),
        "methods": {k: {"label": m.label, "available": m.available, "reason": m.reason} for k, m in methods.items()},
        "not_run": [],
    }
    results: dict = {"meta": meta, "sections": {}}
    device = "cpu"  # accuracy sections solve on the CPU in float64; the speed section times CUDA separately
    for name in SECTIONS:
        if name not in cfg.sections:
            continue
        log(f"[bench] section {name}")
        ts = time.perf_counter()
        try:
            sec = _run_section(name, cfg, methods, device, log)
        except Exception as err:  # keep the other sections; the error is reported in JSON and markdown
            log(traceback.format_exc())
            sec = {"error": f"{type(err).__name__}: {err}"}
        sec["seconds"] = time.perf_counter() - ts
        results["sections"][name] = sec
        log(f"[bench] section {name} done in {sec['seconds']:.1f}s")
    meta["seconds"] = time.perf_counter() - t0
    meta["skipped"] = _skipped(meta, results["sections"])
    boxplot = None
    if "real" in results["sections"] and "sets" in results["sections"]["real"]:
        boxplot = draw_boxplot(results["sections"]["real"], out / "real_rms_boxplot.png")
    write_json(out / "results.json", results)
    (out / "report.md").write_text(render_markdown(results, boxplot.name if boxplot else None), encoding="utf-8")
    if markdown is not None:
        write_markdown(results, markdown, boxplot)
    log(f"[bench] done in {meta['seconds'] / 60:.1f} min; results in {out}")
    return results


#: section -> (module, function, what it takes besides ``cfg`` and ``log``: the methods, the device)
SECTION_RUNNERS: dict[str, tuple[str, str, bool, bool]] = {
    "corners": ("ccs_kornia.bench.sections.corners", "run_corners", True, False),
    "calibration": ("ccs_kornia.bench.sections.calibration", "run_calibration", True, True),
    "real": ("ccs_kornia.bench.sections.real", "run_real", True, True),
    "distortion": ("ccs_kornia.bench.sections.distortion", "run_distortion", True, True),
    "wild": ("ccs_kornia.bench.sections.wild", "run_wild", True, False),
    "fisheye": ("ccs_kornia.bench.sections.fisheye", "run_fisheye", False, False),
    "rig": ("ccs_kornia.bench.sections.rig", "run_rig", False, False),
    "markers": ("ccs_kornia.bench.sections.markers", "run_markers", False, False),
    "rig_sessions": ("ccs_kornia.bench.sections.rig_sessions", "run_rig_sessions", False, False),
    "hand_eye": ("ccs_kornia.bench.sections.hand_eye", "run_hand_eye", False, False),
    "speed": ("ccs_kornia.bench.sections.speed", "run_speed", True, False),
    "video": ("ccs_kornia.bench.sections.video", "run_video", False, False),
    "imu": ("ccs_kornia.bench.sections.imu", "run_imu", False, False),
    "guidance": ("ccs_kornia.bench.sections.guidance", "run_guidance", False, False),
    "precision": ("ccs_kornia.bench.sections.precision", "run_precision", False, False),
    "real_poor": ("ccs_kornia.bench.sections.real_poor", "run_real_poor", False, False),
    "action_camera": ("ccs_kornia.bench.sections.action_camera", "run_action_camera", False, False),
}


def _run_section(name: str, cfg, methods: dict, device: str, log) -> dict:
    """One section's figures: its module imported on demand (a section's dependencies load only when it runs)."""
    module, function, takes_methods, takes_device = SECTION_RUNNERS[name]
    run = getattr(importlib.import_module(module), function)
    args = [cfg] + ([methods] if takes_methods else []) + ([device] if takes_device else [])
    return run(*args, log=log)


def _skipped(meta: dict, sections: dict) -> list[str]:
    """Every method, section, set or device that did not run, with the reason."""
    out = [f"{m['label']}: {m['reason']}" for m in meta["methods"].values() if not m["available"]]
    for name, sec in sections.items():
        if "error" in sec:
            out.append(f"section {name}: failed ({sec['error']})")
        if "skipped" in sec and isinstance(sec["skipped"], str):
            out.append(f"section {name}: {sec['skipped']}")
        for item, why in (sec.get("skipped") or {}).items() if isinstance(sec.get("skipped"), dict) else ():
            out.append(f"{name} {item}: {why}")
        for dev, why in (sec.get("skipped_devices") or {}).items():
            out.append(f"{name} on {dev}: {why}")
        if sec.get("not_in_section"):
            out.append(f"{name}: not run for " + ", ".join(sec["not_in_section"]) + " (calib_methods)")
    return out
