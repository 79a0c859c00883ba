"""How long ``calibrate`` takes to say that ``--board`` is wrong: the early stop after the first detection batch (the
views there searched for a board of another size) against the whole run with every second look.

Runs the command line on a real set with a wrong board size, alternating the two, and prints each wall time and the
medians. The early stop is switched off by a ``board_grid_in`` that finds nothing (the whole run's path, as before it
existed). Run it on an idle machine: on shared cores the figures are inflated.

    python -m ccs_kornia.bench.micro.wrong_board        # BoofCV's Bumblebee2 left camera ($CCS_REAL_DATA or ../shared)
    python -m ccs_kornia.bench.micro.wrong_board --images ../shared/data/real/opencv_left --board 8x6 --repeats 3
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

from ccs_kornia.bench.sections.real import default_real_dir

#: the second interpreter's switch: the early stop never finds another board
_WHOLE_RUN = ("import ccs_kornia.modules.detection.checks.board_size as b; b.board_grid_in = lambda image: None; "
              "from ccs_kornia.cli import run; run()")


def _time(images: str, board: str, early: bool, output: str) -> tuple[float, int, str]:
    command = [sys.executable, "-m", "ccs_kornia"] if early else [sys.executable, "-c", _WHOLE_RUN]
    start = time.perf_counter()
    done = subprocess.run([*command, "calibrate", images, "--board", board, "--output", output],
                          capture_output=True, text=True, env={**os.environ, "PYTHONPATH": os.getcwd()})
    seconds = time.perf_counter() - start
    errors = [line for line in done.stderr.splitlines() if "error:" in line]
    return seconds, done.returncode, errors[-1] if errors else ""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--images", default=str(default_real_dir() / "boofcv_bumblebee2_left"))
    parser.add_argument("--board", default="5x7", help="a wrong board size for the set (the set's is 4x6)")
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    figures: dict[str, list[float]] = {"early stop": [], "whole run": []}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):
            for name, early in (("whole run", False), ("early stop", True)):
                seconds, code, message = _time(args.images, args.board, early, os.path.join(tmp, "c.json"))
                figures[name].append(seconds)
                print(f"{name}: {seconds:.1f} s, exit {code}: {message[:160]}")
    for name, values in figures.items():
        print(f"{name}: median {statistics.median(values):.1f} s over {len(values)} runs")


if __name__ == "__main__":
    main()
