"""The command-line program's exit (``cli.run``): the status of ``main``, exit handlers run, streams flushed, and no
interpreter teardown."""

from __future__ import annotations

import subprocess
import sys


def _program(code: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=120)


def test_status_handlers_and_flushed_output(tmp_path):
    # a thread that is not a daemon is waited for, an exit handler registered while the command ran still runs, after
    # the command's own output, and the piped (block-buffered) output arrives whole
    code = ("import atexit, sys, threading, time; from ccs_kornia import cli; "
            "atexit.register(lambda: print('handler ran')); print('x' * 100_000); "
            "threading.Thread(target=lambda: (time.sleep(0.3), print('thread done'))).start(); "
            "sys.argv = ['ccs-kornia', *sys.argv[1:]]; cli.run()")
    proc = _program(code, "calibrate", str(tmp_path), "--board", "9by6", "--output", str(tmp_path / "c.json"))
    assert proc.returncode == 2 and "invalid board size" in proc.stderr
    lines = proc.stdout.splitlines()
    assert lines == ["x" * 100_000, "thread done", "handler ran"]


def test_success_status_and_module_entry():
    proc = subprocess.run([sys.executable, "-m", "ccs_kornia", "--help"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "calibrate" in proc.stdout and proc.stderr == ""


def test_teardown_is_skipped():
    # a finaliser of an object still alive at the end is the interpreter's teardown: it does not run (the exit
    # handlers do, above)
    code = ("import sys; from ccs_kornia import cli\n"
            "class Late:\n    def __del__(self): print('teardown ran', flush=True)\n"
            "keep = Late(); sys.argv = ['ccs-kornia', '--help']; cli.run()")
    proc = _program(code)
    assert proc.returncode == 0 and "usage" in proc.stdout and "teardown ran" not in proc.stdout
