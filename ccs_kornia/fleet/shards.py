"""The output of ``calibrate-many``: one JSON Lines file, one line per image set, written by one or many processes.

One process appends its lines to the output file itself. In a distributed run (DDP over processes, GPUs or nodes)
every rank appends to its own *shard* beside the output, ``<output>.rank<R>``, so no two processes ever write one
file (which also holds on network file systems, where appends from several nodes interleave and file locks are not
reliable); once every rank is done, rank 0 merges the shards into the output, in the order the sets were given, and
removes them.

Resuming reads the output and every shard (a run may have been stopped between a rank's write and the merge, or run
with another number of processes): a set with a complete line in any of them is done. A line cut short by an
interruption is not complete; it is cut off before a process appends to that file again. A set is written once: a
merge skips sets the output already holds.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Iterator, Sequence

__all__ = [
    "shard_path",
    "shard_files",
    "read_lines",
    "not_jsonl_reason",
    "finished_sets",
    "trim_partial_line",
    "merge_shards",
    "set_outcomes",
]

_SHARD = re.compile(r"\.rank(\d+)$")


def shard_path(output: str, rank: int, world_size: int) -> str:
    """The file rank ``rank`` of ``world_size`` processes appends its lines to.

    Example:
        >>> shard_path("out.jsonl", 0, 1), shard_path("out.jsonl", 1, 2)
        ('out.jsonl', 'out.jsonl.rank1')
    """
    return output if world_size == 1 else f"{output}.rank{rank}"


def shard_files(output: str) -> list[str]:
    """The shards beside ``output`` (``<output>.rank<R>``), by rank.

    Example:
        >>> shard_files("/nonexistent/out.jsonl")
        []
    """
    directory, base = os.path.split(os.path.abspath(output))
    if not os.path.isdir(directory):
        return []
    ranks = []
    for name in os.listdir(directory):
        match = _SHARD.search(name)
        if match and name[: match.start()] == base:
            ranks.append((int(match.group(1)), os.path.join(os.path.dirname(output), name)))
    return [path for _, path in sorted(ranks)]


def read_lines(path: str) -> Iterator[tuple[int, int, dict | None]]:
    """The complete lines of a file: ``(offset, length, record)`` with ``record`` the line's JSON object, or
    ``None`` where the line is not a JSON object with a ``set`` key. A last line without its newline (cut short) is
    not complete and not given; blank lines are not given.

    Example:
        >>> list(read_lines("/nonexistent.jsonl"))
        []
    """
    if not os.path.isfile(path):
        return
    offset = 0
    with open(path, "rb") as handle:
        for line in handle:
            if not line.endswith(b"\n"):
                return
            if not line.strip():  # a blank line says nothing
                offset += len(line)
                continue
            try:
                record = json.loads(line)
            except ValueError:
                record = None
            if not (isinstance(record, dict) and "set" in record):
                record = None
            yield offset, len(line), record
            offset += len(line)


def not_jsonl_reason(path: str) -> str | None:
    """Why ``path`` cannot be appended to as a ``calibrate-many`` output, or ``None`` when it can (missing, empty, or
    JSON Lines of ``calibrate-many``, each line a JSON object with a ``set`` key).

    Example:
        >>> not_jsonl_reason("/nonexistent.jsonl") is None
        True
    """
    why = "the file is not calibrate-many's JSON Lines (a pretty-printed JSON file, for instance)"
    end = 0
    for number, (offset, length, record) in enumerate(read_lines(path), 1):
        if record is None:
            return f"line {number} is not one JSON object with a \"set\" key: {why}"
        end = offset + length
    if os.path.isfile(path) and os.path.getsize(path) > end:  # a last line without its newline
        with open(path, "rb") as handle:
            handle.seek(end)
            tail = handle.read()
        try:
            record = json.loads(tail)
        except ValueError:
            return None  # an interrupted write: cut off before appending
        if not (isinstance(record, dict) and "set" in record):
            return f"it ends in a JSON text that is not a calibrate-many line: {why}"
    return None


def finished_sets(path: str) -> set[str]:
    """Names of the sets with a complete line in a ``calibrate-many`` output file or in any of its shards.

    A last line cut short by an interruption is ignored (its set will be done again).

    Example:
        >>> finished_sets("/nonexistent.jsonl")
        set()
    """
    done: set[str] = set()
    for file in [path, *shard_files(path)]:
        done.update(str(record["set"]) for _, _, record in read_lines(file) if record is not None)
    return done


def trim_partial_line(path: str) -> None:
    """Cut a last line without its newline (an interrupted write), so appended lines start clean."""
    if not os.path.isfile(path) or os.path.getsize(path) == 0:
        return
    with open(path, "rb+") as handle:
        data = handle.read()
        if data.endswith(b"\n"):
            return
        handle.seek(data.rfind(b"\n") + 1)
        handle.truncate()


def merge_shards(output: str, order: Sequence[str] = ()) -> int:
    """Append the shards' lines of the sets ``output`` does not hold yet, then remove the shards (rank 0, once every
    rank is done).

    Lines go in the order of ``order`` (the sets as given), sets not in it after them; one line per set. The output is
    synced to disk before a shard is removed, so a stop at any point loses nothing (a rerun merges again).

    Args:
        output: the output file.
        order: set names in the order their lines should take.

    Returns:
        The number of lines appended.
    """
    shards = shard_files(output)
    if not shards:
        return 0
    trim_partial_line(output)
    done = {str(r["set"]) for _, _, r in read_lines(output) if r is not None}
    rank_of = {name: k for k, name in enumerate(order)}
    found: dict[str, tuple[int, int, int]] = {}  # set -> (shard, offset, length): offsets only, not the lines
    for s, shard in enumerate(shards):
        for offset, length, record in read_lines(shard):
            if record is not None and str(record["set"]) not in done:
                found.setdefault(str(record["set"]), (s, offset, length))
    names = sorted(found, key=lambda n: (rank_of.get(n, len(rank_of)), n))
    handles = [open(shard, "rb") for shard in shards]  # noqa: SIM115 (closed below)
    try:
        with open(output, "ab") as out:
            for name in names:
                s, offset, length = found[name]
                handles[s].seek(offset)
                out.write(handles[s].read(length))
            out.flush()
            os.fsync(out.fileno())
    finally:
        for handle in handles:
            handle.close()
    for shard in shards:
        os.remove(shard)
    return len(names)


def set_outcomes(path: str, names: Sequence[str]) -> dict[str, bool]:
    """``success`` of each of ``names`` that has a line in ``path`` (the first line of a set counts).

    Example:
        >>> set_outcomes("/nonexistent.jsonl", ["a"])
        {}
    """
    wanted = set(names)
    out: dict[str, bool] = {}
    for _, _, record in read_lines(path):
        if record is not None and str(record["set"]) in wanted:
            out.setdefault(str(record["set"]), bool(record.get("success")))
    return out
