"""``ccs_kornia imu-noise``: a still log's noise written as Kalibr's imu.yaml (values recovered from a log of known
noise), the figure, the units caught, and the refusals (a log that moves, one too short, a malformed one)."""

from __future__ import annotations

import math
import re

import cv2
import numpy as np
import pytest

from ccs_kornia import cli
from ccs_kornia.io.imu import GRAVITY
from ccs_kornia.io.kalibr import read_imu_yaml
from ccs_kornia.runtime.errors import EXIT_OK, EXIT_USAGE

EUROC_HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],"
                "a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")
RATE = 100.0
#: the noise of the rendered IMU: gyroscope (rad/s/sqrt(Hz), rad/s^2/sqrt(Hz)), accelerometer (m/s^2/sqrt(Hz),
#: m/s^3/sqrt(Hz)); the random walks show after some 10 s
GYRO, ACCEL = (1e-3, 2e-4), (8e-3, 1.6e-3)


def _still_log(seconds: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A still IMU of known noise: ns timestamps, rad/s (a bias each), m/s^2 (gravity along z)."""
    rng = np.random.default_rng(seed)
    n = int(seconds * RATE)
    t = 1_600_000_000_000_000_000 + np.arange(n, dtype=np.int64) * int(1e9 / RATE)

    def sensor(white: float, walk: float, bias) -> np.ndarray:
        steps = walk / math.sqrt(RATE) * rng.standard_normal((n, 3))
        return white * math.sqrt(RATE) * rng.standard_normal((n, 3)) + np.cumsum(steps, 0) + np.asarray(bias)

    return t, sensor(*GYRO, [0.003, -0.01, 0.02]), sensor(*ACCEL, [0.05, -0.1, GRAVITY])


def _write(path, t, gyro, accel, header: str = EUROC_HEADER) -> str:
    with open(path, "w") as handle:
        handle.write(header + "\n")
        handle.writelines(f"{a},{b[0]:.10g},{b[1]:.10g},{b[2]:.10g},{c[0]:.10g},{c[1]:.10g},{c[2]:.10g}\n"
                          for a, b, c in zip(t.tolist(), gyro, accel))
    return str(path)


@pytest.fixture(scope="module")
def still(tmp_path_factory):
    """Twenty minutes of a still IMU at 100 Hz, EuRoC's layout."""
    return _write(tmp_path_factory.mktemp("imu") / "static.csv", *_still_log(1200.0))


def test_noise_of_a_still_log(still, tmp_path, capsys):
    out, plot = tmp_path / "imu.yaml", tmp_path / "allan.png"
    code = cli.main(["imu-noise", still, "--output", str(out), "--plot", str(plot), "--rostopic", "/vi/imu"])
    captured = capsys.readouterr()
    assert code == EXIT_OK, captured.err
    assert f"{still}: timestamps in ns (the header says so)" in captured.err
    assert "warning" not in captured.err and "error" not in captured.err
    noise = read_imu_yaml(str(out))
    assert noise.update_rate == RATE
    assert noise.gyroscope_noise_density == pytest.approx(GYRO[0], rel=0.02)
    assert noise.accelerometer_noise_density == pytest.approx(ACCEL[0], rel=0.02)
    assert noise.gyroscope_random_walk == pytest.approx(GYRO[1], rel=0.2)
    assert noise.accelerometer_random_walk == pytest.approx(ACCEL[1], rel=0.2)
    assert "rostopic: /vi/imu" in out.read_text()
    lines = captured.out.splitlines()
    assert lines[0] == f"{still}: 120000 samples at 100 Hz over 0.33 h"
    assert lines[2].startswith("gyroscope x") and len(lines) == 11 and lines[-1].startswith("written (the mean")
    figure = cv2.imread(str(plot))
    assert figure is not None and figure.shape == (900, 900, 3)


def test_units_caught_and_said(tmp_path, capsys):
    t, gyro, accel = _still_log(1200.0, seed=1)
    header = "time [ns],gyro_x [deg/s],gyro_y [deg/s],gyro_z [deg/s],acc_x,acc_y,acc_z"
    path = _write(tmp_path / "units.csv", t, np.degrees(gyro), accel / GRAVITY, header)
    code = cli.main(["imu-noise", path, "--output", str(tmp_path / "imu.yaml")])
    err = capsys.readouterr().err
    assert code == EXIT_OK, err
    assert "gyroscope in deg/s (the header says so): converted to rad/s" in err
    assert re.search(r"units.csv: accelerometer in g \(median \|a\| (0\.99|1\.00)\d*, about 1\): converted to m/s\^2", err)
    noise = read_imu_yaml(str(tmp_path / "imu.yaml"))
    assert noise.gyroscope_noise_density == pytest.approx(GYRO[0], rel=0.02)
    assert noise.accelerometer_noise_density == pytest.approx(ACCEL[0], rel=0.02)


def _refused(argv, capsys, output) -> str:
    code = cli.main(argv)
    err = capsys.readouterr().err
    assert code == EXIT_USAGE and len(err.splitlines()) == 1 and err.startswith("ccs_kornia imu-noise: error: "), err
    assert not output.exists()
    return err


def test_a_log_that_moves_is_refused(tmp_path, capsys):
    t, gyro, accel = _still_log(300.0)
    seconds = np.arange(len(t)) / RATE
    gyro = gyro + 0.8 * np.sin(2 * np.pi * 0.3 * seconds)[:, None]  # turned by hand
    out = tmp_path / "imu.yaml"
    err = _refused(["imu-noise", _write(tmp_path / "moving.csv", t, gyro, accel), "--output", str(out)], capsys, out)
    assert "the log is not still: the gyroscope's median |w - its median| is 0.98 rad/s" in err
    assert "record the IMU lying at rest" in err


def test_a_log_too_short_says_how_long_is_needed(tmp_path, capsys):
    out = tmp_path / "imu.yaml"
    path = _write(tmp_path / "short.csv", *_still_log(60.0))
    err = _refused(["imu-noise", path, "--output", str(out), "--plot", str(tmp_path / "a.png")], capsys, out)
    assert "gyroscope x: the log is 60 s long" in err and "the random walk cannot be read" in err
    assert "record a still log of at least" in err and not (tmp_path / "a.png").exists()


def test_a_malformed_log_is_refused(tmp_path, capsys):
    t, gyro, accel = _still_log(10.0)
    path = _write(tmp_path / "bad.csv", t, gyro, accel)
    lines = (tmp_path / "bad.csv").read_text().splitlines()
    lines[41] = lines[41].replace(",", ";", 1)
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    out = tmp_path / "imu.yaml"
    err = _refused(["imu-noise", path, "--output", str(out)], capsys, out)
    assert "bad.csv: line 42 has 6 fields, expected 7" in err
    err = _refused(["imu-noise", str(tmp_path / "none.csv"), "--output", str(out)], capsys, out)
    assert "none.csv: no such file" in err


def test_help(capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.build_parser().parse_args(["imu-noise", "--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    assert "--output YAML" in text and "--plot PNG" in text and "-1/2 slope line at 1 s" in text
    assert "exit status:" in text
