"""Every Python code block of the README runs as written (in order, sharing one namespace), and prints what its
comments say it prints."""

from __future__ import annotations

import builtins
import re
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"

#: a comment that states a printed value starts with one of these; what follows ``...``, `` (`` or ``; `` explains it
_CLAIM = re.compile(r"^\s*print\(.*\)\s+#\s*((?:True|False|torch\.Size)\b.*)$")


def _python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.S)


def claims(block: str) -> dict[int, str]:
    """Line number (1-based, in the block) -> the start of what that line's ``print`` must print.

    Example:
        >>> claims("x = 1\\nprint(x)   # True '' (or False)\\nprint(y)  # the poses\\n")
        {2: "True ''"}
    """
    out = {}
    for number, line in enumerate(block.splitlines(), 1):
        match = _CLAIM.match(line)
        if match:
            out[number] = re.split(r"\.\.\.| \(|; ", match.group(1), maxsplit=1)[0].rstrip()
    return out


def test_readme_has_python_examples():
    blocks = _python_blocks()
    assert len(blocks) >= 2
    assert sum(len(claims(b)) for b in blocks) >= 4  # the printed values the examples promise


def test_claims_are_read_from_the_comments():
    assert claims("print(bool(bad.success), bad.camera_reasons)    # False 'board found in 0; ...'\n") == {
        1: "False 'board found in 0"}
    assert claims("print(uv.grad.shape)  # torch.Size([10, 54, 2]); 0 for unused views\n") == {
        1: "torch.Size([10, 54, 2])"}
    assert claims("print(out.K, out.dist)  # (3, 3), (5,) OpenCV order\n") == {}


@pytest.mark.slow
def test_readme_python_blocks_run_and_print_what_they_say():
    printed: dict[tuple[str, int], list[str]] = {}

    def recording_print(*args, sep=" ", **kwargs):
        caller = sys._getframe(1)
        printed.setdefault((caller.f_code.co_filename, caller.f_lineno), []).append(sep.join(str(a) for a in args))
        builtins.print(*args, sep=sep, **kwargs)

    namespace: dict = {"__name__": "__readme__", "print": recording_print}
    expected = {}
    for k, block in enumerate(_python_blocks()):
        name = f"README.md python block {k}"
        expected.update({(name, line): claim for line, claim in claims(block).items()})
        try:
            exec(compile(block, name, "exec"), namespace)  # noqa: S102
        except Exception as err:  # pragma: no cover - the failure message is the point
            pytest.fail(f"README python block {k} failed: {type(err).__name__}: {err}\n{block}")
    for (name, line), claim in expected.items():
        lines = printed.get((name, line))
        assert lines, f"{name}, line {line} printed nothing; its comment says {claim!r}"
        assert all(text.startswith(claim) for text in lines), f"{name}, line {line} printed {lines}, not {claim!r}"
    out = namespace["out"]  # the shapes the comments give
    assert tuple(out.K.shape) == (3, 3) and tuple(out.dist.shape) == (5,)
    assert tuple(out.view_rms.shape) == tuple(out.used.shape) == tuple(out.found.shape) == (10,)
    assert tuple(out.rvec.shape) == tuple(out.tvec.shape) == (10, 3) and tuple(out.std.shape) == (9,)
