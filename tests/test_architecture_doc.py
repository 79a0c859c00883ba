"""``docs/architecture.md`` names what exists: every path and folder it names is in the tree, every folder of the
package and every command of the command line is named there."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "ccs_kornia"
PAGE = ROOT / "docs" / "architecture.md"

#: a file (``a/b.py``, ``lens.py``, ``gpu_check.sh``) or a folder (``render/``, ``modules/detection/``); neither part
#: of a longer path nor of a dotted name
_PATH = re.compile(r"(?<![\w./-])((?:[A-Za-z_][\w.]*/)*[A-Za-z_]\w*(?:\.(?:py|sh|md|yaml)|/))(?![\w/])")


def named_paths(text: str) -> list[str]:
    """The files and folders a page names, in order.

    Example:
        >>> named_paths("data/ holds `render/lens.py`; see docs/rig.md, not 3/4 or e.g. a.b.c")
        ['data/', 'render/lens.py', 'docs/rig.md']
    """
    return [m.group(1) for m in _PATH.finditer(text)]


def _tree() -> tuple[set[str], set[str]]:
    files, dirs = set(), set()
    for p in PACKAGE.rglob("*"):
        if "__pycache__" in p.parts:
            continue
        rel = p.relative_to(PACKAGE).as_posix()
        (dirs.add(rel + "/") if p.is_dir() else files.add(rel))
    return files, dirs


def _exists(name: str, files: set[str], dirs: set[str]) -> bool:
    """A path named on the page exists: from the repository root, or in the package whole or as the end of a path
    (the page names paths relative to the folder it is describing)."""
    if (ROOT / name).exists():
        return True
    pool = dirs if name.endswith("/") else files
    if "/" not in name.rstrip("/"):
        return any(p == name or p.endswith("/" + name) for p in pool)
    return name in pool or any(p.endswith("/" + name) for p in pool)


def test_the_page_names_paths():
    names = named_paths(PAGE.read_text(encoding="utf-8"))
    assert len(names) > 200
    for expected in ("pipeline/calibration_pipeline.py", "schur_lm.py", "data/", "render/", "bench/", "sections/"):
        assert expected in names, expected


def test_every_named_path_exists():
    files, dirs = _tree()
    text = PAGE.read_text(encoding="utf-8")
    missing = [f"line {text[: m.start()].count(chr(10)) + 1}: {m.group(1)}" for m in _PATH.finditer(text)
               if not _exists(m.group(1), files, dirs)]
    assert not missing, "\n".join(missing)


def test_every_folder_of_the_package_is_named():
    _, dirs = _tree()
    names = set(named_paths(PAGE.read_text(encoding="utf-8")))
    short = {n.rstrip("/").rsplit("/", 1)[-1] + "/" for n in names if n.endswith("/")}
    unnamed = sorted(d for d in dirs if d.rstrip("/").rsplit("/", 1)[-1] + "/" not in short)
    assert not unnamed, unnamed


def test_every_command_is_named():
    from ccs_kornia.cli import build_parser

    action = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    commands = sorted(action.choices)
    assert {"detect", "calibrate", "calibrate-rig", "bench", "fit"} <= set(commands)
    text = PAGE.read_text(encoding="utf-8")
    unnamed = [c for c in commands if f"`{c}`" not in text]
    assert not unnamed, unnamed
