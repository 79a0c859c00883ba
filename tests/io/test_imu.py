"""IMU logs in (``io/imu.py``): the layouts, the units told and converted, the refusals, the findings."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ccs_kornia.io import imu
from ccs_kornia.io.imu import GRAVITY, ImuLog, ImuNoise, imu_log_findings, read_imu_csv
from ccs_kornia.runtime.errors import UserError

EUROC_HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],"
                "a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")


def _samples(n: int = 400, rate: float = 200.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` samples of a hand-held motion: seconds, rad/s (peaks near 2 rad/s), m/s^2 (gravity on z)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    gyro = np.stack([2.0 * np.sin(2 * np.pi * 0.5 * t + k) for k in range(3)], 1) + 0.01 * rng.standard_normal((n, 3))
    accel = np.array([0.3, -0.2, GRAVITY]) + 0.5 * np.stack([np.cos(2 * np.pi * 0.7 * t + k) for k in range(3)], 1)
    return t, gyro, accel


def _write(path, header: str | None, rows: list[str]) -> str:
    path.write_text(((header + "\n") if header is not None else "") + "\n".join(rows) + "\n")
    return str(path)


def _rows(t, gyro, accel, time_fmt=lambda x: f"{x:.9f}", order=None) -> list[str]:
    cols = [t, *gyro.T, *accel.T]
    order = order or list(range(7))
    return [",".join(time_fmt(cols[0][i]) if c == 0 else f"{cols[c][i]:.9g}" for c in order) for i in range(len(t))]


def _close(log: ImuLog, t, gyro, accel, t0: float = 0.0) -> None:
    assert log.t.dtype == torch.float64 and log.gyro.shape == (len(t), 3) and log.accel.shape == (len(t), 3)
    assert np.allclose(log.t.numpy() - t0, t, atol=1e-6)
    assert np.allclose(log.gyro.numpy(), gyro, rtol=1e-7, atol=1e-9)
    assert np.allclose(log.accel.numpy(), accel, rtol=1e-7, atol=1e-9)


def test_euroc_layout(tmp_path):
    t, gyro, accel = _samples()
    start = 1403636579758555392
    rows = _rows(t, gyro, accel, time_fmt=lambda x: str(start + round(x * 1e9)))
    log = read_imu_csv(_write(tmp_path / "data.csv", EUROC_HEADER, rows))
    _close(log, t, gyro, accel, t0=start * 1e-9)
    assert log.notes == ["timestamps in ns (the header says so)"]
    assert len(log) == 400 and log.duration == pytest.approx(399 / 200.0, abs=1e-6)


@pytest.mark.parametrize("names", [
    "timestamp,wx,wy,wz,ax,ay,az",
    "time,gyro_x,gyro_y,gyro_z,acc_x,acc_y,acc_z",
    "t,omega_x,omega_y,omega_z,accel_x,accel_y,accel_z",
    ("stamp,angular_velocity.x,angular_velocity.y,angular_velocity.z,linear_acceleration.x,linear_acceleration.y,"
     "linear_acceleration.z"),
])
def test_plain_headers(tmp_path, names):
    t, gyro, accel = _samples()
    log = read_imu_csv(_write(tmp_path / "imu.csv", names, _rows(t, gyro, accel)))
    _close(log, t, gyro, accel)
    assert log.notes == ["timestamps in s (by the sample period)"]


def test_named_columns_in_any_order_and_extra_columns(tmp_path):
    t, gyro, accel = _samples()
    header = "ax,ay,az,temperature,wz,wy,wx,timestamp"
    cols = [*accel.T, np.full(len(t), 31.5), gyro[:, 2], gyro[:, 1], gyro[:, 0], t]
    rows = [",".join(f"{c[i]:.9g}" for c in cols) for i in range(len(t))]
    _close(read_imu_csv(_write(tmp_path / "imu.csv", header, rows)), t, gyro, accel)


def test_no_header_white_space_and_comments(tmp_path):
    t, gyro, accel = _samples()
    rows = [r.replace(",", "  ") for r in _rows(t, gyro, accel)]
    rows.insert(10, "# a comment line")
    rows.insert(20, "")
    _close(read_imu_csv(_write(tmp_path / "imu.txt", None, rows)), t, gyro, accel)


@pytest.mark.parametrize("unit,factor,start", [("ns", 1e9, 0.0), ("us", 1e6, 0.0), ("ms", 1e3, 0.0), ("s", 1.0, 0.0),
                                                ("ns", 1e9, 1.7e9), ("us", 1e6, 1.7e9), ("ms", 1e3, 1.7e9),
                                                ("s", 1.0, 1.7e9)])
def test_time_units_told_by_the_numbers(tmp_path, unit, factor, start):
    t, gyro, accel = _samples()
    rows = _rows(t, gyro, accel, time_fmt=lambda x: f"{(start + x) * factor:.6f}")
    log = read_imu_csv(_write(tmp_path / "imu.csv", None, rows))
    assert log.notes[0].startswith(f"timestamps in {unit} (")
    assert np.allclose(log.t.numpy() - start, t, atol=2e-6)


def test_gyroscope_in_degrees_is_converted(tmp_path):
    t, gyro, accel = _samples()
    log = read_imu_csv(_write(tmp_path / "imu.csv", None, _rows(t, np.degrees(gyro) * 10, accel)))
    assert np.allclose(log.gyro.numpy(), gyro * 10, rtol=1e-7)
    assert any(n.startswith("gyroscope in deg/s (99th percentile of |w|") and n.endswith("converted to rad/s")
               for n in log.notes)
    # slow motion in deg/s is not told by the numbers, but by a header that names the unit
    header = "t,wx [deg/s],wy [deg/s],wz [deg/s],ax,ay,az"
    log = read_imu_csv(_write(tmp_path / "named.csv", header, _rows(t, np.degrees(gyro), accel)))
    assert np.allclose(log.gyro.numpy(), gyro, rtol=1e-7)
    assert "gyroscope in deg/s (the header says so): converted to rad/s" in log.notes


def test_accelerometer_in_g_is_converted(tmp_path):
    t, gyro, accel = _samples()
    log = read_imu_csv(_write(tmp_path / "imu.csv", None, _rows(t, gyro, accel / GRAVITY)))
    assert np.allclose(log.accel.numpy(), accel, rtol=1e-7)
    assert any(n.startswith("accelerometer in g (median |a|") for n in log.notes)
    assert not any("gyroscope" in n for n in log.notes)


def test_rows_of_a_chunk_after_the_first_are_named_by_their_line(tmp_path, monkeypatch):
    monkeypatch.setattr(imu, "_CHUNK", 64)
    t, gyro, accel = _samples()
    rows = _rows(t, gyro, accel)
    rows[300] = rows[300].rsplit(",", 1)[0]
    path = _write(tmp_path / "imu.csv", "timestamp,wx,wy,wz,ax,ay,az", rows)
    with pytest.raises(UserError, match=r"line 302 has 6 fields, expected 7"):
        read_imu_csv(path)
    rows = _rows(t, gyro, accel)
    log = read_imu_csv(_write(tmp_path / "ok.csv", None, rows))
    _close(log, t, gyro, accel)  # the chunks join in order


@pytest.mark.parametrize("edit,message", [
    (lambda rows: rows.__setitem__(150, rows[150] + ",1.0"), r"imu.csv: line 151 has 8 fields, expected 7"),
    (lambda rows: rows.__setitem__(150, rows[150].replace(",", ",abc,", 1).rsplit(",", 1)[0]),
     r"imu.csv: line 151 is not numeric \('abc'"),
    (lambda rows: rows.__setitem__(150, ",".join(rows[150].split(",")[:3] + ["nan"] + rows[150].split(",")[4:])),
     r"imu.csv: line 151 holds NaN or infinite values; 1 such row"),
    (lambda rows: rows.__setitem__(150, rows[149]), r"imu.csv: the timestamp repeats at line 151"),
    (lambda rows: rows.__setitem__(150, rows[100]), r"imu.csv: the timestamp goes backwards at line 151"),
    (lambda rows: rows.__delitem__(slice(99, None)), r"imu.csv: 99 samples; an IMU log needs at least 100"),
])
def test_refusals_name_the_line(tmp_path, edit, message):
    t, gyro, accel = _samples()
    rows = _rows(t, gyro, accel)
    edit(rows)
    with pytest.raises(UserError, match=message) as err:
        read_imu_csv(_write(tmp_path / "imu.csv", None, rows))
    assert "\n" not in str(err.value)


def test_refusals_of_the_file(tmp_path):
    t, gyro, accel = _samples()
    with pytest.raises(UserError, match="no such file"):
        read_imu_csv(str(tmp_path / "missing.csv"))
    with pytest.raises(UserError, match=r"the header names no column for ax, ay, az"):
        read_imu_csv(_write(tmp_path / "h.csv", "timestamp,wx,wy,wz,q1,q2,q3", _rows(t, gyro, accel)))
    with pytest.raises(UserError, match=r"line 1 has 6 fields; a log without a header takes 7"):
        read_imu_csv(_write(tmp_path / "six.csv", None, [r.rsplit(",", 1)[0] for r in _rows(t, gyro, accel)]))
    removed = 0.6 * np.sin(2 * np.pi * 0.5 * t)[:, None].repeat(3, 1)  # gravity removed: |a| down to zero
    with pytest.raises(UserError, match=r"median \|a\| is 0.7.*5th percentile 0.0.*neither m/s\^2 \(about 9.8\) nor g"):
        read_imu_csv(_write(tmp_path / "a.csv", None, _rows(t, gyro, removed)))
    with pytest.raises(UserError, match=r"neither ns, us, ms nor s"):
        read_imu_csv(_write(tmp_path / "t.csv", None, _rows(t * 1e-3, gyro, accel, time_fmt=lambda x: f"{x:.12f}")))
    (tmp_path / "bin.csv").write_bytes(b"\xff\xfe\x00\x01" * 100)
    with pytest.raises(UserError, match="not a text file"):
        read_imu_csv(str(tmp_path / "bin.csv"))


def test_findings_of_a_clean_log():
    t, gyro, accel = _samples(1000)
    findings = imu_log_findings(ImuLog(*(torch.from_numpy(a) for a in (t, gyro, accel))))
    assert findings.rate == pytest.approx(200.0, rel=1e-9)
    assert findings.dropped == 0 and findings.longest_gap == pytest.approx(0.005)
    assert findings.saturated == [] and findings.messages() == []


def test_findings_of_dropped_and_clipped_samples():
    t, gyro, accel = _samples(2000)
    keep = np.ones(len(t), bool)
    keep[[500, 900, 901, 902]] = False  # one sample dropped, then three in a row
    gyro[:, 1] = np.clip(gyro[:, 1], -1.5, 1.5)  # the y axis at the end of its range
    accel[:, 0] = np.round(accel[:, 0] * 100) / 100  # quantised, not clipped
    log = ImuLog(*(torch.from_numpy(np.ascontiguousarray(a[keep])) for a in (t, gyro, accel)))
    findings = imu_log_findings(log)
    assert findings.dropped == 2 and findings.longest_gap == pytest.approx(0.02)
    assert findings.rate == pytest.approx(200.0, rel=1e-9)
    clipped = float(np.mean(np.abs(gyro[keep, 1]) == 1.5))
    assert findings.gyro_saturation[1] == pytest.approx(clipped) and clipped > 0.1
    assert findings.gyro_saturation[0] == 0 and findings.accel_saturation == (0.0, 0.0, 0.0)
    assert findings.saturated == ["gyroscope y"]
    messages = findings.messages()
    assert messages[0].startswith("2 gap(s) longer than 1.5 sample periods") and "0.02 s" in messages[0]
    assert messages[1] == f"gyroscope y clipped in {100 * clipped:.1f} % of the samples"


def test_rate_of_an_epoch_clock_in_float64():
    # an epoch time in float64 is quantised (0.24 us): the rate is still read to 1e-6
    t = 1.7e9 + np.arange(5000) / 400.0
    zeros = torch.zeros(5000, 3, dtype=torch.float64)
    findings = imu_log_findings(ImuLog(torch.from_numpy(t), zeros, zeros))
    assert findings.rate == pytest.approx(400.0, rel=1e-6)


def test_imu_log_shapes():
    with pytest.raises(ValueError, match=r"t \(N,\), gyro \(N, 3\) and accel \(N, 3\)"):
        ImuLog(torch.zeros(5, dtype=torch.float64), torch.zeros(5, 2, dtype=torch.float64),
               torch.zeros(5, 3, dtype=torch.float64))


def test_euroc_noise():
    noise = ImuNoise.euroc()
    assert (noise.accelerometer_noise_density, noise.accelerometer_random_walk, noise.gyroscope_noise_density,
            noise.gyroscope_random_walk, noise.update_rate) == (1.86e-03, 4.33e-04, 1.87e-04, 2.66e-05, 200.0)
    assert noise.discrete_accelerometer_sigma == pytest.approx(1.86e-03 * math.sqrt(200.0))
