"""Markdown of the speed section's limit: network floors, the detector's and the default path's stage profiles,
the real set end to end, next to the speed targets (used by :mod:`ccs_kornia.bench.report.report`)."""

from __future__ import annotations

__all__ = ["TARGETS", "limit_markdown"]

#: the speed targets on 2 CPU cores at 640x480
TARGETS = {"detect_b16": 50.0, "detect_b1": 25.0, "calibration_s": 1.0, "end_to_end_s": 6.0}


def _n(v, digits: int = 2) -> str:
    return "—" if v is None else f"{v:.{digits}f}"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)] + ["| " + " | ".join(r) + " |" for r in rows] + [""]


def limit_markdown(lim: dict, detection: dict, calibration: dict) -> list[str]:
    """Lines for one device's ``limit`` entry; ``detection`` / ``calibration`` are the section's tables (for the
    side-by-side OpenCV figures of the same run)."""
    fl = lim["floors"]
    rates = fl["rates_gflops"]
    prec = fl["unet_precision"]
    g = fl["gflop_per_image"]
    lines = ["**The limit.** Measured conv rate (channels-last convolution stack of the UNet's shapes, same threads, "
             "this run): " + ", ".join(f"{k} {v:.1f} GFLOP/s" for k, v in rates.items())
             + f". The heatmap UNet runs in {prec}; its detection levels for these images: "
             + ", ".join(f"{k} x{n}" for k, n in fl["unet_levels"].items()) + ".", ""]
    rows = []
    for key, label in (("unet_level", "heatmap UNet, detection levels"), ("unet_full", "heatmap UNet, full resolution"),
                       ("distortion", "DistortionNet, 256x256 input")):
        if key not in g:
            continue
        floor = {dt: fl["floor_ms_per_image"].get(f"{key}@{dt}") for dt in rates}
        rows.append([label, _n(g[key], 3)] + [_n(floor[dt], 1) for dt in rates])
    lines += _table(["network", "GFLOP / image"] + [f"floor ms / image ({dt})" for dt in rates], rows)
    det = lim["detector"]
    batches = [b for b in det if b != "precision"]
    stages = list(dict.fromkeys(k for b in batches for k in det[b]["stages"]))
    net_floor = fl["floor_ms_per_image"].get(f"unet_level@{prec}")
    rows = [[st] + [_n(det[b]["stages"].get(st), 1) for b in batches] for st in stages]
    rows.append(["**total (img/s)**"] + [f"{1000 / det[b]['images_per_s']:.1f} ({det[b]['images_per_s']:.1f})"
                                         for b in batches])
    # the network's own time bounds the detector's rate; the floor at the plain convolution rate can be above what the
    # network measures (its convolutions run faster than the benchmark stack's), so the smaller of the two is the bound
    big = max(batches, key=int) if batches else None
    net_ms = det[big]["stages"].get("heatmap network") if big else None
    bound = min(x for x in (net_floor, net_ms) if x) if (net_floor or net_ms) else None
    lines += ["Learned detector, ms per image by stage (exclusive times; the network's floor at the detection levels is "
              f"{_n(net_floor, 1)} ms at the plain convolution rate and it measured {_n(net_ms, 1)} ms at batch {big}, "
              f"so detection cannot exceed {_n(1000 / bound if bound else None, 1)} img/s here whatever the rest "
              "costs):", ""]
    lines += _table(["stage"] + [f"batch {b}" for b in batches], rows)
    pipe = lim["pipeline"]
    rows = [[r["stage"], _n(r["seconds"], 3), f"{100 * r['share']:.1f} %", str(r["calls"])] for r in pipe["stages"]]
    serial = pipe.get("serial_wall_s", pipe["wall_s"])
    rows.append(["**wall, one process**", _n(serial, 3), "100 %", ""])
    if "workers" in pipe and pipe["workers"] > 1:
        rows.append([f"**wall, {pipe['workers']} worker processes (as `calibrate`)**", _n(pipe["wall_s"], 3), "", ""])
    lines += [f"Default path (`CalibrationPipeline`: learned detector, correction on, batches of "
              f"{pipe.get('batch_size', 16)}) on {pipe['views']} views written as PNG files, per stage in one process "
              f"(exclusive; found {pipe['found']}/{pipe['views']}):", ""]
    lines += _table(["stage", "s", "share", "calls"], rows)
    e2e = lim.get("end_to_end")
    if e2e:
        if "wall_s" in e2e:
            lines += [f"`{e2e['command']}` ({e2e['set']}): {_n(e2e['wall_s'])} s wall in a fresh interpreter "
                      f"(pipeline {_n(e2e.get('pipeline_s'))} s; {e2e.get('views_used')} views, RMS {_n(e2e.get('rms'), 3)} px).", ""]
        else:
            lines += [f"End to end on {e2e['set']}: not run ({e2e.get('skipped') or e2e.get('error')}).", ""]
    # the targets, with OpenCV's figures of the same run beside ours
    learned = next((r for k, r in detection.items() if k == "learned"), None)
    cv = detection.get("opencv_subpix")
    rows = []
    if learned:
        for b, key in (("16", "detect_b16"), ("1", "detect_b1")):
            got = learned["images_per_s"].get(b) or learned["images_per_s"].get(max(learned["images_per_s"], key=int))
            rows.append([f"learned detection img/s, batch {b}", f">= {TARGETS[key]:.0f}", _n(got, 1),
                         _n((cv or {}).get("images_per_s", {}).get(b), 1)])
        work = learned.get("workers")
        if work:
            rows.append([f"learned detection img/s, {work['processes']} worker processes, batches of {work['batch']}",
                         f">= {TARGETS['detect_b16']:.0f}", _n(work["images_per_s"], 1),
                         _n((cv or {}).get("images_per_s", {}).get("16"), 1)])
    ours = next((r for label, r in calibration.items() if "CalibrationPipeline" in label), None)
    theirs = next((r for label, r in calibration.items() if label.startswith("OpenCV")), None)
    if ours:
        rows.append(["whole calibration s (default path, in memory, one process)", f"<= {TARGETS['calibration_s']:.1f}",
                     _n(ours["seconds"]), _n((theirs or {}).get("seconds"))])
    if "workers" in pipe:
        rows.append([f"whole calibration s (PNG files as `calibrate` reads them, {pipe['workers']} process(es))",
                     f"<= {TARGETS['calibration_s']:.1f}", _n(pipe["wall_s"]), _n((theirs or {}).get("seconds"))])
    if e2e and "wall_s" in e2e:
        rows.append([f"{e2e['set']} end to end s", f"<= {TARGETS['end_to_end_s']:.0f}", _n(e2e["wall_s"]), "—"])
    lines += ["The speed targets (2 CPU cores, 640x480) against this run, OpenCV classic + cornerSubPix of the same "
              "run beside:", ""]
    lines += _table(["figure", "target", "ccs_kornia", "OpenCV"], rows)
    return lines
