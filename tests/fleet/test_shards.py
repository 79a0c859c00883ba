"""Tests of ccs_kornia.fleet.shards: calibrate-many's JSON Lines output, its per-rank shards and their merge."""

from __future__ import annotations

import json

import pytest

from ccs_kornia.fleet.shards import (
    finished_sets,
    merge_shards,
    not_jsonl_reason,
    read_lines,
    set_outcomes,
    shard_files,
    shard_path,
    trim_partial_line,
)


def _line(name: str, success: bool = True) -> str:
    return json.dumps({"set": name, "success": success, "error": None if success else "no board"}) + "\n"


def test_shard_paths(tmp_path):
    out = str(tmp_path / "x.jsonl")
    assert shard_path(out, 0, 1) == out
    assert [shard_path(out, r, 3) for r in range(3)] == [f"{out}.rank{r}" for r in range(3)]
    for name in ("x.jsonl.rank10", "x.jsonl.rank2", "x.jsonl.rankA", "y.jsonl.rank0", "x.jsonl.rank1.tmp"):
        (tmp_path / name).write_text("")
    assert shard_files(out) == [f"{out}.rank2", f"{out}.rank10"]  # by rank, only ``<output>.rank<digits>``


def test_read_lines_skips_a_cut_last_line(tmp_path):
    path = tmp_path / "x.jsonl"
    path.write_text(_line("a") + "not json\n" + '{"no_set": 1}\n' + '{"set": "half')
    got = list(read_lines(str(path)))
    assert [r["set"] if r else None for _, _, r in got] == ["a", None, None]
    assert got[1][0] == len(_line("a"))  # offsets and lengths of the complete lines
    assert sum(length for _, length, _ in got) == len(path.read_bytes()) - len('{"set": "half')


def test_not_jsonl_reason(tmp_path):
    good, cut, pretty, compact, empty = (tmp_path / n for n in ("g", "c", "p", "o", "e"))
    good.write_text(_line("a") + _line("b", False))
    cut.write_text(_line("a") + '{"set": "b", "succ')  # an interrupted write: resumable
    pretty.write_text(json.dumps({"K": [[1, 0], [0, 1]], "rms": 0.1}, indent=1) + "\n")
    compact.write_text(json.dumps({"K": [[1, 0], [0, 1]]}))  # one JSON text, no newline: not ours either
    empty.write_text("")
    for path in (good, cut, empty, tmp_path / "missing"):
        assert not_jsonl_reason(str(path)) is None, path
    assert "line 1" in not_jsonl_reason(str(pretty)) and "pretty-printed" in not_jsonl_reason(str(pretty))
    assert "not a calibrate-many line" in not_jsonl_reason(str(compact))


def test_finished_sets_reads_the_output_and_every_shard(tmp_path):
    out = tmp_path / "x.jsonl"
    out.write_text(_line("a"))
    (tmp_path / "x.jsonl.rank0").write_text(_line("b") + '{"set": "c"')  # c was cut short: not finished
    (tmp_path / "x.jsonl.rank3").write_text(_line("d", False))  # left by a run with more processes
    assert finished_sets(str(out)) == {"a", "b", "d"}


def test_merge_shards_in_the_given_order_once_per_set(tmp_path):
    out = tmp_path / "x.jsonl"
    out.write_text(_line("b") + '{"set": "cut')
    (tmp_path / "x.jsonl.rank0").write_text(_line("a") + _line("c") + _line("zz"))
    (tmp_path / "x.jsonl.rank1").write_text(_line("b") + _line("d", False) + '{"set": "e"')
    added = merge_shards(str(out), ["a", "b", "c", "d", "e"])
    assert added == 4  # b was in the output already, e never finished
    assert [json.loads(line)["set"] for line in out.read_text().splitlines()] == ["b", "a", "c", "d", "zz"]
    assert shard_files(str(out)) == []
    assert merge_shards(str(out), ["a"]) == 0  # nothing left to merge
    assert set_outcomes(str(out), ["a", "d", "e"]) == {"a": True, "d": False}


def test_trim_partial_line(tmp_path):
    path = tmp_path / "x.jsonl"
    path.write_text(_line("a") + '{"set": "b')
    trim_partial_line(str(path))
    assert path.read_text() == _line("a")
    trim_partial_line(str(path))  # a clean file is left as it is
    assert path.read_text() == _line("a")


@pytest.mark.parametrize("content", ["", "\n", _line("a") + "\n \n"])
def test_blank_lines_say_nothing(tmp_path, content):
    path = tmp_path / "x.jsonl"
    path.write_text(content)
    assert finished_sets(str(path)) == ({"a"} if content.startswith("{") else set())
    assert not_jsonl_reason(str(path)) is None
