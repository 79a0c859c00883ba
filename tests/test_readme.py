"""Every Python code block of the README runs as written (in order, sharing one namespace)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def _python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.S)


def test_readme_has_python_examples():
    assert len(_python_blocks()) >= 2


@pytest.mark.slow
def test_readme_python_blocks_run(capsys):
    namespace: dict = {"__name__": "__readme__"}
    for k, block in enumerate(_python_blocks()):
        try:
            exec(compile(block, f"README.md python block {k}", "exec"), namespace)  # noqa: S102
        except Exception as err:  # pragma: no cover - the failure message is the point
            pytest.fail(f"README python block {k} failed: {type(err).__name__}: {err}\n{block}")
    printed = capsys.readouterr().out
    assert "True" in printed  # the first example calibrates; the last one reproduces the whole call
    assert "False" in printed  # the random images are refused with a reason
    assert bool(namespace["out"].success) and not bool(namespace["bad"].success)
    assert namespace["bad"].camera_reasons
