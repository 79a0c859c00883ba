"""IMU logs in: a CSV of timestamps, gyroscope and accelerometer readings (EuRoC's layout, a plain header or none),
read in chunks, checked, and converted to seconds, rad/s and m/s^2, with what was inferred said in words.

:func:`read_imu_csv` reads a log into an :class:`ImuLog`; what stops a log from being used (a malformed row, too few
samples, timestamps that go backwards or repeat, NaN) raises a one-line
:class:`~ccs_kornia.runtime.errors.UserError`. What only weakens it (dropped samples, clipped axes) is
:func:`imu_log_findings`' :class:`ImuFindings`, data for a verdict. :class:`ImuNoise` holds Kalibr's four noise values
of an IMU and its rate.

Units are told from the header where it names them (``[ns]``, ``[rad s^-1]``, ``deg/s``, ``[g]``), else from the
numbers:

* timestamps: an epoch time is told by its magnitude (a date between 1973 and 2286 is ``1e8 .. 1e10`` s, ``1e11 ..
  1e13`` ms, ``1e14 .. 1e16`` us, ``1e17 .. 1e19`` ns); a time from zero by its median step, read as a rate between 5 Hz
  and 5 kHz in exactly one of the four units;
* gyroscope: deg/s where the 99th percentile of ``|w|`` exceeds :data:`GYRO_DEG_THRESHOLD` (20 rad/s, over 1100 deg/s:
  beyond any hand-held or vehicle motion, while a motion in deg/s passes it at 20 deg/s);
* accelerometer: g where the median ``|a|`` is between 0.5 and 2 (gravity dominates any calibration motion's median),
  m/s^2 between 4.9 and 19.6, and in either unit the 5th percentile of ``|a|`` over 0.3 g (gravity is always there);
  anything else (a log with gravity removed, mg) is refused.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np
import torch

from ccs_kornia.geometry.imu_noise import ImuNoise
from ccs_kornia.runtime.errors import UserError

__all__ = [
    "GRAVITY",
    "GYRO_DEG_THRESHOLD",
    "MIN_SAMPLES",
    "ImuFindings",
    "ImuLog",
    "ImuNoise",
    "imu_log_findings",
    "read_imu_csv",
]

#: standard gravity (m/s^2): the accelerometer's g converted
GRAVITY = 9.80665
#: the 99th percentile of ``|w|`` (rad/s) above which a gyroscope is read as deg/s
GYRO_DEG_THRESHOLD = 20.0
#: the fewest samples a log may have
MIN_SAMPLES = 100
#: a gap longer than this many median periods counts as dropped samples
GAP_FACTOR = 1.5
#: rows parsed at once (the log is read in chunks of this many lines)
_CHUNK = 200_000
#: the time units by their factor to seconds
_TIME_UNITS = {"ns": 1e-9, "us": 1e-6, "ms": 1e-3, "s": 1.0}


@dataclass
class ImuLog:
    """An IMU log in seconds, rad/s and m/s^2.

    Args:
        t: :math:`(N,)` float64 timestamps in seconds, strictly increasing.
        gyro: :math:`(N, 3)` float64 angular rates (rad/s) in the IMU's frame.
        accel: :math:`(N, 3)` float64 specific forces (m/s^2) in the IMU's frame.
        notes: what the reader inferred and converted, in words (``"timestamps in ns (by their magnitude)"``,
            ``"gyroscope in deg/s: converted to rad/s"``, ...).

    Example:
        >>> t = torch.arange(200, dtype=torch.float64) / 200
        >>> log = ImuLog(t, torch.zeros(200, 3, dtype=torch.float64), torch.zeros(200, 3, dtype=torch.float64))
        >>> len(log), round(log.duration, 3)
        (200, 0.995)
    """

    t: torch.Tensor
    gyro: torch.Tensor
    accel: torch.Tensor
    notes: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        n = self.t.shape[0] if self.t.dim() == 1 else -1
        if n < 0 or self.gyro.shape != (n, 3) or self.accel.shape != (n, 3):
            raise ValueError(f"an ImuLog takes t (N,), gyro (N, 3) and accel (N, 3); got {tuple(self.t.shape)}, "
                             f"{tuple(self.gyro.shape)}, {tuple(self.accel.shape)}")

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def duration(self) -> float:
        """Seconds from the first sample to the last."""
        return float(self.t[-1] - self.t[0]) if len(self) else 0.0


@dataclass(frozen=True)
class ImuFindings:
    """What weakens an IMU log without stopping its use: data for a verdict.

    Args:
        rate: the measured rate (Hz): one over the mean period, gaps left out.
        dropped: gaps longer than :data:`GAP_FACTOR` median periods.
        longest_gap: the longest period (s).
        gyro_saturation: per axis (x, y, z) the fraction of samples at the axis' extreme value repeated (clipped).
        accel_saturation: the same for the accelerometer.

    Example:
        >>> findings = ImuFindings(200.0, 0, 0.005, (0.0, 0.0, 0.0), (0.0, 0.0, 0.01))
        >>> findings.messages()
        ['accelerometer z clipped in 1.0 % of the samples']
    """

    rate: float
    dropped: int
    longest_gap: float
    gyro_saturation: tuple[float, float, float]
    accel_saturation: tuple[float, float, float]

    @property
    def saturated(self) -> list[str]:
        """The clipped axes' names (``"gyroscope x"``, ``"accelerometer z"``, ...)."""
        return [f"{sensor} {axis}" for sensor, fractions in (("gyroscope", self.gyro_saturation),
                                                             ("accelerometer", self.accel_saturation))
                for axis, fraction in zip("xyz", fractions) if fraction > 0]

    def messages(self) -> list[str]:
        """The findings in words, one line each (none for a clean log)."""
        out = []
        if self.dropped:
            out.append(f"{self.dropped} gap(s) longer than {GAP_FACTOR:g} sample periods (dropped samples; the "
                       f"longest {self.longest_gap:.4g} s at {self.rate:.4g} Hz)")
        for sensor, fractions in (("gyroscope", self.gyro_saturation), ("accelerometer", self.accel_saturation)):
            for axis, fraction in zip("xyz", fractions):
                if fraction > 0:
                    out.append(f"{sensor} {axis} clipped in {100 * fraction:.1f} % of the samples")
        return out


# ----------------------------------------------------------------------------------------------
# the header
# ----------------------------------------------------------------------------------------------

_GYRO_NAMES = {"w", "omega", "gyro", "gyr", "g", "gyroscope", "wrss", "angularvelocity", "fieldangularvelocity",
               "angvel", "angrate", "rate"}
_ACCEL_NAMES = {"a", "acc", "accel", "accelerometer", "acceleration", "arss", "linearacceleration",
                "fieldlinearacceleration", "linacc"}
_TIME_NAMES = {"timestamp", "time", "t", "stamp", "ts", "fieldheaderstamp", "headerstamp", "timestamps"}
_UNIT = re.compile(r"\[([^\]]*)\]|\(([^)]*)\)")


def _column_role(name: str) -> tuple[str, str]:
    """``(role, unit)`` of a header name: role ``"t"``, ``"wx"`` .. ``"az"`` or ``""``; unit the bracketed or suffixed
    unit in words (``"ns"``, ``"deg/s"``, ``"g"``, ``""``)."""
    text = name.strip().lstrip("#%").strip().lower()
    unit = _unit_words(" ".join(a or b for a, b in _UNIT.findall(text)))
    text = _UNIT.sub("", text).strip()
    bare = re.sub(r"[^a-z0-9]", "", text)
    timed = re.fullmatch(r"(timestamp|time|stamp|t|ts)(ns|us|ms|s|sec|nsec)?", bare)
    if bare in _TIME_NAMES or timed:
        return "t", unit or (_unit_words(timed.group(2)) if timed and timed.group(2) else "")
    axis = re.fullmatch(r"(.*?)[^a-z0-9]*([xyz])(?:[^a-z0-9]+(dps|degs|deg|rads|g|mss))?", text)
    if axis:
        unit = unit or _unit_words(axis.group(3) or "")
        stem = re.sub(r"[^a-z0-9]", "", axis.group(1))
        if stem in _GYRO_NAMES:
            return "w" + axis.group(2), unit
        if stem in _ACCEL_NAMES:
            return "a" + axis.group(2), unit
    return "", unit


def _unit_words(text: str) -> str:
    """A header's unit text as one of ``ns us ms s rad/s deg/s m/s^2 g`` (``""`` when none or unknown)."""
    t = text.replace(" ", "").replace("^", "")
    times = {"ns": ("ns", "nsec", "nanoseconds"), "us": ("us", "usec", "µs", "microseconds"),
             "ms": ("ms", "msec", "milliseconds"), "s": ("s", "sec", "seconds")}
    for unit, names in times.items():
        if t in names:
            return unit
    if "deg" in t or t in ("dps", "°/s"):
        return "deg/s"
    if "rad" in t:
        return "rad/s"
    if t == "g":
        return "g"
    if t.startswith("m/s") or t in ("ms-2", "mss", "mps2"):
        return "m/s^2"
    return ""


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _split(line: str, delimiter: str | None) -> list[str]:
    return [f.strip() for f in (line.split(delimiter) if delimiter else line.split())]


def _layout(path: str, header: str, delimiter: str | None) -> tuple[list[int], dict[str, str], int]:
    """The columns of ``t wx wy wz ax ay az`` in a header's order, the units the header names per role, and the
    header's field count."""
    fields = _split(header, delimiter)
    roles: dict[str, int] = {}
    units: dict[str, str] = {}
    for i, name in enumerate(fields):
        role, unit = _column_role(name)
        if role and role not in roles:
            roles[role] = i
            if unit:
                units[role] = unit
    wanted = ("t", "wx", "wy", "wz", "ax", "ay", "az")
    missing = [r for r in wanted if r not in roles]
    if missing and len(fields) == 7 and fields[0].lstrip().startswith("#") and not roles:
        roles = dict(zip(wanted, range(7)))  # a commented header of seven unknown names: the columns in order
        missing = []
    if missing:
        raise UserError(f"{path}: the header names no column for {', '.join(missing)} (expected timestamp, wx, wy, "
                        f"wz, ax, ay, az, or EuRoC's #timestamp [ns],w_RS_S_x [rad s^-1],...; got {header.strip()!r})")
    return [roles[r] for r in wanted], units, len(fields)


# ----------------------------------------------------------------------------------------------
# the rows
# ----------------------------------------------------------------------------------------------


def _parse_chunk(path: str, lines: list[str], numbers: list[int], delimiter: str | None, width: int) -> np.ndarray:
    """The rows of ``lines`` as an ``(n, width)`` float64 array; the first malformed row raises, named by its line."""
    try:
        with np.errstate(all="ignore"):
            out = np.loadtxt(lines, delimiter=delimiter, dtype=np.float64, ndmin=2)
        if out.shape[1] == width:
            return out
    except ValueError:
        pass
    for line, number in zip(lines, numbers):
        fields = _split(line, delimiter)
        if len(fields) != width:
            raise UserError(f"{path}: line {number} has {len(fields)} fields, expected {width} ({line.strip()[:80]!r})")
        bad = next((f for f in fields if not _is_number(f)), None)
        if bad is not None:
            raise UserError(f"{path}: line {number} is not numeric ({bad!r} in {line.strip()[:80]!r})")
    raise UserError(f"{path}: rows that are not {width} numbers each")  # pragma: no cover - loadtxt agrees above


def _read_rows(path: str) -> tuple[np.ndarray, dict[str, str], np.ndarray]:
    """The log's ``t wx wy wz ax ay az`` columns ``(N, 7)``, the header's units and each row's line number (1-based),
    read in chunks of :data:`_CHUNK` lines (the line numbers kept as an array: a Python list of them would outweigh
    the log)."""
    try:
        handle = open(path, encoding="utf-8-sig")  # noqa: SIM115 (closed by the with below, after the errors of opening)
    except FileNotFoundError:
        raise UserError(f"{path}: no such file") from None
    except OSError as err:
        raise UserError(f"{path}: cannot be read ({err.strerror or err})") from None
    columns: list[int] = list(range(7))
    units: dict[str, str] = {}
    delimiter: str | None = None
    width = 0
    chunks: list[np.ndarray] = []
    line_numbers: list[np.ndarray] = []
    lines: list[str] = []
    numbers: list[int] = []
    with handle:
        try:
            for number, line in enumerate(handle, 1):
                stripped = line.strip()
                if not stripped:
                    continue
                if not width:  # the first line that is not blank: a header or the first row
                    delimiter = "," if "," in stripped else (";" if ";" in stripped else None)
                    fields = _split(stripped, delimiter)
                    if stripped.startswith(("#", "%")) or not all(_is_number(f) for f in fields):
                        columns, units, width = _layout(path, stripped, delimiter)
                        continue
                    width = len(fields)
                    if width != 7:
                        raise UserError(f"{path}: line {number} has {width} fields; a log without a header takes 7 "
                                        "(t, wx, wy, wz, ax, ay, az)")
                if stripped.startswith("#"):
                    continue  # a comment
                lines.append(stripped)
                numbers.append(number)
                if len(lines) == _CHUNK:
                    chunks.append(_parse_chunk(path, lines, numbers, delimiter, width)[:, columns])
                    line_numbers.append(np.array(numbers, dtype=np.int64))
                    lines, numbers = [], []
        except UnicodeDecodeError:
            raise UserError(f"{path}: not a text file (an IMU log is a CSV of numbers)") from None
    if lines:
        chunks.append(_parse_chunk(path, lines, numbers, delimiter, width)[:, columns])
        line_numbers.append(np.array(numbers, dtype=np.int64))
    data = np.concatenate(chunks) if chunks else np.zeros((0, 7))
    return data, units, np.concatenate(line_numbers) if line_numbers else np.zeros(0, np.int64)


# ----------------------------------------------------------------------------------------------
# units
# ----------------------------------------------------------------------------------------------


def _time_unit(t: np.ndarray, named: str) -> tuple[str, str]:
    """``(unit, how it was told)`` of raw timestamps."""
    if named in _TIME_UNITS:
        return named, "the header says so"
    start = abs(float(t[0]))
    for unit, low in (("s", 1e8), ("ms", 1e11), ("us", 1e14), ("ns", 1e17)):
        if low <= start < 100 * low:
            return unit, "an epoch time, by its magnitude"
    step = float(np.median(np.diff(t)))
    for unit, factor in _TIME_UNITS.items():
        if 2e-4 <= step * factor < 0.2:  # a rate between 5 Hz and 5 kHz
            return unit, "by the sample period"
    raise UserError(f"timestamps of median step {step:.6g} from {t[0]:.6g}: neither ns, us, ms nor s of an IMU's "
                    "rate (5 Hz to 5 kHz)")


def _check_times(path: str, t: np.ndarray, lines: np.ndarray) -> None:
    step = np.diff(t)
    bad = np.flatnonzero(~(step > 0))
    if bad.size:
        k = int(bad[0])
        what = "repeats" if step[k] == 0 else "goes backwards"
        raise UserError(f"{path}: the timestamp {what} at line {lines[k + 1]} ({t[k + 1]:.9g} after {t[k]:.9g} on line "
                        f"{lines[k]}); {bad.size} such step(s) in all: timestamps must increase")


def read_imu_csv(path: str) -> ImuLog:
    """Read an IMU log: a CSV of timestamps, gyroscope and accelerometer readings.

    Layouts: EuRoC's (``#timestamp [ns],w_RS_S_x [rad s^-1],...,a_RS_S_z [m s^-2]``), a plain header naming the
    columns in any order (``timestamp``/``time``/``t``, ``wx``/``gyro_x``/``omega_x``/``angular_velocity_x``,
    ``ax``/``acc_x``/``accel_x``/``linear_acceleration_x``, ...; other columns ignored), or no header (then ``t, wx, wy,
    wz, ax, ay, az``). Commas, semicolons or white space between fields; lines starting with ``#`` after the first are
    comments. Units as the module says; what was inferred and converted is in the log's ``notes``.

    Args:
        path: the CSV file.

    Returns:
        the log in seconds (on the file's own clock: an epoch time stays one), rad/s and m/s^2.

    Raises:
        UserError: one line: no such file, a header without the columns, a row of another field count or not numeric
            (its line number), NaN or infinite values (the line), fewer than :data:`MIN_SAMPLES` rows, timestamps that
            repeat or go backwards (the line), units that cannot be told.

    Example:
        >>> import os, tempfile
        >>> rows = [f"{1403636579758555392 + 5_000_000 * i},0.01,0.02,-0.01,9.8,0.1,0.2" for i in range(200)]
        >>> path = os.path.join(tempfile.mkdtemp(), "imu.csv")
        >>> _ = open(path, "w").write("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
        ...                           "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\\n" + "\\n".join(rows))
        >>> log = read_imu_csv(path)
        >>> len(log), round(float(log.t[1] - log.t[0]), 6), log.gyro.dtype, log.notes
        (200, 0.005, torch.float64, ['timestamps in ns (the header says so)'])
    """
    data, units, lines = _read_rows(path)
    if len(data) < MIN_SAMPLES:
        raise UserError(f"{path}: {len(data)} samples; an IMU log needs at least {MIN_SAMPLES}")
    finite = np.isfinite(data).all(1)
    if not finite.all():
        k = int(np.flatnonzero(~finite)[0])
        raise UserError(f"{path}: line {lines[k]} holds NaN or infinite values; {int((~finite).sum())} such row(s)")
    notes = []
    raw_t = data[:, 0]
    _check_times(path, raw_t, lines)
    try:
        unit, how = _time_unit(raw_t, units.get("t", ""))
    except UserError as err:
        raise UserError(f"{path}: {err}") from None
    notes.append(f"timestamps in {unit} ({how})")
    t = raw_t * _TIME_UNITS[unit]
    gyro, accel = data[:, 1:4].copy(), data[:, 4:7].copy()
    gyro_unit = units.get("wx", "")
    p99 = float(np.percentile(np.linalg.norm(gyro, axis=1), 99))
    if gyro_unit == "deg/s" or (gyro_unit != "rad/s" and p99 > GYRO_DEG_THRESHOLD):
        gyro *= math.pi / 180.0
        why = "the header says so" if gyro_unit == "deg/s" else (
            f"99th percentile of |w| {p99:.4g}, over {GYRO_DEG_THRESHOLD:g} rad/s")
        notes.append(f"gyroscope in deg/s ({why}): converted to rad/s")
    accel_unit = units.get("ax", "")
    norm = np.linalg.norm(accel, axis=1)
    median, low = float(np.median(norm)), float(np.percentile(norm, 5))
    if accel_unit == "g" or (accel_unit != "m/s^2" and 0.5 <= median <= 2.0 and low >= 0.3):
        accel *= GRAVITY
        why = "the header says so" if accel_unit == "g" else f"median |a| {median:.4g}, about 1"
        notes.append(f"accelerometer in g ({why}): converted to m/s^2")
    elif accel_unit != "m/s^2" and not (0.5 * GRAVITY <= median <= 2.0 * GRAVITY and low >= 0.3 * GRAVITY):
        raise UserError(f"{path}: the accelerometer's median |a| is {median:.4g} (5th percentile {low:.4g}): neither "
                        "m/s^2 (about 9.8) nor g (about 1) with gravity in it; the log must hold the specific force "
                        "with gravity (not removed)")
    return ImuLog(torch.from_numpy(np.ascontiguousarray(t)), torch.from_numpy(gyro), torch.from_numpy(accel), notes)


# ----------------------------------------------------------------------------------------------
# findings
# ----------------------------------------------------------------------------------------------


def _clipped_fraction(x: np.ndarray) -> float:
    """The fraction of samples of one axis at its extreme values where they pile up: an extreme read at least 5 times
    and over 3 times as often as the next value inward. A sensor at the end of its range reads its limit again and
    again, while a signal's tail (quantised or not) thins out towards its extremes."""
    values, counts = np.unique(x, return_counts=True)
    if len(values) < 2:
        return 0.0
    count = 0
    for hits, inner in ((counts[-1], counts[-2]), (counts[0], counts[1])):
        if hits >= 5 and hits > 3 * inner:
            count += int(hits)
    return count / len(x)


def imu_log_findings(log: ImuLog) -> ImuFindings:
    """What weakens a log without stopping it: dropped samples, clipped axes, the measured rate.

    Args:
        log: the log (:func:`read_imu_csv`).

    Returns:
        the findings (gaps over :data:`GAP_FACTOR` median periods, per axis the fraction of clipped samples).

    Example:
        >>> t = torch.cat([torch.arange(100), torch.arange(103, 200)]).double() / 100
        >>> gyro = torch.randn(197, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
        >>> gyro[:20, 0] = 5.0  # clipped at its range
        >>> findings = imu_log_findings(ImuLog(t, gyro, torch.ones(197, 3, dtype=torch.float64)))
        >>> findings.rate, findings.dropped, round(findings.longest_gap, 3), findings.saturated
        (100.0, 1, 0.04, ['gyroscope x'])
    """
    t = log.t.detach().cpu().double().numpy()
    step = np.diff(t)
    period = float(np.median(step)) if step.size else float("nan")
    regular = step[step <= GAP_FACTOR * period]
    # the mean of the regular periods, not their median: an epoch time in float64 is quantised (0.24 us at today's
    # dates), and the quantisation cancels in a mean (the sum telescopes) but not in a median
    rate = 1.0 / float(regular.mean()) if regular.size and period > 0 else float("nan")
    dropped = int(np.count_nonzero(step > GAP_FACTOR * period)) if step.size else 0
    gyro = log.gyro.detach().cpu().double().numpy()
    accel = log.accel.detach().cpu().double().numpy()
    return ImuFindings(
        rate=rate,
        dropped=dropped,
        longest_gap=float(step.max()) if step.size else 0.0,
        gyro_saturation=tuple(_clipped_fraction(gyro[:, k]) for k in range(3)),  # type: ignore[arg-type]
        accel_saturation=tuple(_clipped_fraction(accel[:, k]) for k in range(3)),  # type: ignore[arg-type]
    )
