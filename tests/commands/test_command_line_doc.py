"""docs/command_line.md lists every option of every command, and nothing else: checked against the parsers."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from ccs_kornia.cli import LIGHTNING_COMMANDS, build_parser

DOC = Path(__file__).resolve().parents[2] / "docs" / "command_line.md"


def _parsers() -> dict[str, argparse.ArgumentParser]:
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return {name: p for name, p in sub.choices.items() if name not in (*LIGHTNING_COMMANDS, "bench")}


def _documented() -> dict[str, tuple[set[str], list[str]]]:
    out = {}
    for line in DOC.read_text(encoding="utf-8").splitlines():
        m = re.match(r"\* \*\*`([a-z-]+)`\*\*(.*?):(.*)$", line)
        if m:
            out[m.group(1)] = (set(re.findall(r"`(--[a-z0-9-]+)`", m.group(3))), re.findall(r"`([A-Z_]+)`", m.group(2)))
    return out


@pytest.mark.parametrize("command", sorted(_parsers()))
def test_every_option_is_documented(command):
    parser = _parsers()[command]
    options = {o for a in parser._actions for o in a.option_strings if o.startswith("--") and o != "--help"}
    positionals = [a.metavar or a.dest for a in parser._actions if not a.option_strings]
    documented = _documented()
    assert command in documented, f"docs/command_line.md lists no options of {command}"
    listed, listed_positionals = documented[command]
    assert sorted(options - listed) == [], "accepted but not in docs/command_line.md"
    assert sorted(listed - options) == [], "in docs/command_line.md but not accepted"
    assert listed_positionals == positionals


def test_every_command_is_documented():
    assert set(_documented()) == set(_parsers())


@pytest.mark.parametrize("command", sorted(_parsers()))
def test_help_names_only_options_the_command_accepts(command, monkeypatch):
    monkeypatch.setenv("COLUMNS", "1000")  # no option name cut by a line break
    parser = _parsers()[command]
    options = {o for a in parser._actions for o in a.option_strings}
    mentioned = set(re.findall(r"(?<![\w-])(--[a-z][a-z0-9-]*)", parser.format_help()))
    assert sorted(mentioned - options) == []
