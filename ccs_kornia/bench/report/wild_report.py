"""Markdown tables of the ``wild`` section (see :mod:`ccs_kornia.bench.sections.wild`)."""

from __future__ import annotations

__all__ = ["wild_markdown"]

_SHORT = {"learned": "learned", "opencv_saddle": "cv+saddle", "opencv_subpix": "cv subpix", "opencv_sb": "cv SB",
          "libcbdetect": "cbdetect"}


def _n(x, digits: int = 3) -> str:
    return "–" if x is None or x != x else f"{x:.{digits}f}"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    return out + ["| " + " | ".join(r) + " |" for r in rows] + [""]


def wild_markdown(sec: dict) -> list[str]:
    """Lines of the section: one summary table over the conditions, then board-free and real photos."""
    conds = sec.get("conditions", {})
    keys = list(dict.fromkeys(k for c in conds.values() for k in c["methods"]))
    lines = [
        "Renders with exact ground truth (one image at a time, 8-bit, realistic optics on every condition: "
        "0.3-1 px Gaussian point spread, gamma 1.8-2.4, mild noise). *det*: boards detected (mean corner error at "
        f"most max({sec.get('threshold_px', 3):g} px, 5 % of the square)); *wrong*: boards returned but off by more; "
        "*err*: mean corner error (px) on the boards each method detected, *common*: on the images every method "
        "detected; *s*: seconds per image; *MB*: peak memory per image, the growth of the process' peak resident "
        f"set during the call ({sec.get('memory', 'RSS')}). Peers run in a forked child (a crash or more than "
        f"{sec.get('time_limit_s') or '∞'} s on one image counts as no board, marked *crashed* / *timed out*).",
        "",
    ]
    names = [f"{_SHORT.get(k, k)}" for k in keys]

    def label(name: str, c: dict) -> str:
        first = next(iter(c["methods"].values()), {"images": 0})
        return f"{name} ({c['image_size'][0]}x{c['image_size'][1]}, {c['board'][0]}x{c['board'][1]}, {first['images']})"

    def cells(fn) -> list[list[str]]:
        return [[label(n, c)] + [("–" if c["methods"].get(k) is None else fn(c["methods"][k])) for k in keys]
                for n, c in conds.items()]

    head = ["condition (size, board, images)"]
    lines += ["*Detected (wrong boards)*; where some renders hide corners (e.g. a glare saturating black and white "
              "squares alike), *visible*: renders whose every corner the image shows (intensity range of at least "
              "5 % of full scale within a quarter square), and in brackets the boards detected among them; "
              "*p*: of the detected boards, those returned with corners left out (partial boards: glare, a border)",
              ""]
    hidden = any(c.get("visible_images") is not None and c["visible_images"] < next(iter(c["methods"].values()),
                 {"images": 0})["images"] for c in conds.values())

    def detected(c: dict, r: dict) -> str:
        text = f"{r['detected']}/{r['images']} ({r['wrong_boards']})"
        if r.get("partial_boards"):
            text += f" {r['partial_boards']}p"
        v = c.get("visible_images")
        if v is not None and v < r["images"] and r.get("detected_visible") is not None:
            text += f" [{r['detected_visible']}/{v}]"
        return (text + (f" {r['crashes']} crashed" if r.get("crashes") else "")
                + (f" {r['timeouts']} timed out" if r.get("timeouts") else ""))

    rows = [[label(n, c)] + ([str(c.get("visible_images", "–"))] if hidden else [])
            + [("–" if c["methods"].get(k) is None else detected(c, c["methods"][k])) for k in keys]
            for n, c in conds.items()]
    lines += _table(head + (["visible"] if hidden else []) + names, rows)
    lines += ["*Mean corner error, px: own detections / common subset (n)*", ""]
    lines += _table(head + names, cells(lambda r: f"{_n(r['mean_px'])} / {_n(r['mean_common_px'])} ({r['common_images']})"))
    lines += ["*Seconds / peak MB per image*", ""]
    lines += _table(head + names, cells(lambda r: f"{_n(r['seconds_per_image'], 2)} / {_n(r['peak_mb_per_image'], 0)}"))
    lines += ["Conditions: " + "; ".join(f"*{n}*: {c['description']}" for n, c in conds.items()) + ".", ""]
    free = sec.get("board_free") or {}
    if free.get("methods"):
        kinds = ", ".join(f"{k} {v}" for k, v in free.get("kinds", {}).items())
        lines += [f"**Board-free images** ({free['images']}: {kinds}; searched for "
                  + " and ".join(f"{b[0]}x{b[1]}" for b in free["boards_searched"]) + " alternately): false boards "
                  "(target 0).", ""]
        lines += _table(["method", "false boards", "by kind", "s/img"], [
            [r["label"], f"{r['false_boards']}/{free['images']}" + (f" ({r['crashes']} crashed)" if r.get("crashes") else "")
             + (f" ({r['timeouts']} timed out)" if r.get("timeouts") else ""),
             ", ".join(f"{k} {v}" for k, v in r["by_kind"].items()) or "–", _n(r["seconds_per_image"], 2)]
            for r in free["methods"].values()])
    real = sec.get("real") or {}
    if real.get("sets"):
        scales = real["scales"]
        lines += [f"**Real photos rescaled** (`{real['root']}`; no ground truth: boards found per method, "
                  "seconds and peak MB per image at the largest scale; * = a detector ran out of time on some image).", ""]
        header = ["set (board, size, images)"] + [f"{_SHORT.get(k, k)} x{s:g}" for k in keys for s in scales] + \
                 [f"{_SHORT.get(k, k)} s / MB at x{scales[-1]:g}" for k in keys]
        rows = []
        for name, e in real["sets"].items():
            row = [f"{name} ({e['board'][0]}x{e['board'][1]}, {e['image_size'][0]}x{e['image_size'][1]}, {e['images']})"]
            for k in keys:
                for s in scales:
                    r = e["scales"].get(f"{s:g}", {}).get(k)
                    row.append("–" if r is None else f"{r['found']}/{e['images']}" + ("*" if r.get("timeouts") else ""))
            for k in keys:
                r = e["scales"].get(f"{scales[-1]:g}", {}).get(k)
                row.append("–" if r is None else f"{_n(r['seconds_per_image'], 1)} / {_n(r['peak_mb_per_image'], 0)}")
            rows.append(row)
        lines += _table(header, rows)
    for name, why in (real.get("skipped") or {}).items():
        lines.append(f"- real photos, skipped `{name}`: {why}")
    return lines + [""]
