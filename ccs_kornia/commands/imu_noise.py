"""``ccs_kornia imu-noise``: an IMU's noise from a still log (docs/command_line.md): the Allan deviation of each axis,
Kalibr's four values read off it, written as Kalibr's ``imu.yaml`` (and the figure on request).

The log must be still (the IMU at rest) and long enough for the bias random walk to show: the command refuses, in
one line, a log that moves and a log too short, saying how long a log is needed. Every output is written at the end.
"""

from __future__ import annotations

import argparse

import numpy as np

from ccs_kornia.commands._output_paths import check_outputs
from ccs_kornia.commands._printing import info, warn
from ccs_kornia.io.files import write_text_atomic
from ccs_kornia.io.imu import ImuLog, ImuNoise, imu_log_findings, read_imu_csv
from ccs_kornia.modules.imu.allan import AllanNoise, allan_deviation, noise_from_allan
from ccs_kornia.outputs.imu_exports import imu_yaml
from ccs_kornia.outputs.report.allan import allan_figure
from ccs_kornia.outputs.report.drawing import write_png
from ccs_kornia.runtime.errors import UserError

__all__ = ["COMMAND", "MAX_STILL_ACCEL_SPREAD", "MAX_STILL_GYRO_SPREAD", "check_still", "run", "summary_lines"]

COMMAND = "imu-noise"
#: the median of ``|w - median w|`` (rad/s) above which a log is not still: a resting gyroscope's is its noise, a few
#: mrad/s even for a consumer IMU at 1 kHz, while a hand-held or vibrating one's is tenths of rad/s
MAX_STILL_GYRO_SPREAD = 0.05
#: the same for the accelerometer (m/s^2)
MAX_STILL_ACCEL_SPREAD = 0.5


def check_still(log: ImuLog) -> None:
    """Refuse a log that is not still: the median distance of the readings from their per-axis median (the bias at
    rest) is over :data:`MAX_STILL_GYRO_SPREAD` rad/s or :data:`MAX_STILL_ACCEL_SPREAD` m/s^2."""
    for sensor, x, limit, unit in (("gyroscope", log.gyro, MAX_STILL_GYRO_SPREAD, "rad/s"),
                                   ("accelerometer", log.accel, MAX_STILL_ACCEL_SPREAD, "m/s^2")):
        spread = float((x - x.median(0).values).norm(dim=1).median())
        if spread > limit:
            raise UserError(f"the log is not still: the {sensor}'s median |{'w' if unit == 'rad/s' else 'a'} - its "
                            f"median| is {spread:.3g} {unit} (at rest it is its noise, under {limit:g}); record the "
                            "IMU lying at rest, untouched")


def summary_lines(path: str, log: ImuLog, rate: float, fits: dict[str, AllanNoise], noise: ImuNoise) -> list[str]:
    """The result in words for stdout: the log, each axis' values, the values written (the mean of the axes)."""
    hours = log.duration / 3600.0
    lines = [f"{path}: {len(log)} samples at {rate:.6g} Hz over {hours:.2f} h",
             f"{'':16}{'noise density':>18}{'random walk':>18}"]
    for sensor, fit, units in (("gyroscope", fits["gyro"], ("rad/s/sqrt(Hz)", "rad/s^2/sqrt(Hz)")),
                               ("accelerometer", fits["accel"], ("m/s^2/sqrt(Hz)", "m/s^3/sqrt(Hz)"))):
        for axis in range(3):
            lines.append(f"{sensor + ' ' + 'xyz'[axis]:16}{float(fit.noise_density[axis]):18.4e}"
                         f"{float(fit.random_walk[axis]):18.4e}")
        lines.append(f"{'  (units)':16}{units[0]:>18}{units[1]:>18}")
    lines.append(f"written (the mean of the three axes): gyroscope {noise.gyroscope_noise_density:.4e}, "
                 f"{noise.gyroscope_random_walk:.4e}; accelerometer {noise.accelerometer_noise_density:.4e}, "
                 f"{noise.accelerometer_random_walk:.4e}; update_rate {noise.update_rate:g}")
    return lines


def run(args: argparse.Namespace) -> int:
    """The command: read and check the log, the Allan deviations, the noise values, the files."""
    check_outputs(files=[("--output", args.output), ("--plot", args.plot)])
    log = read_imu_csv(args.log)
    findings = imu_log_findings(log)
    check_still(log)
    rate = findings.rate
    fits, curves = {}, {}
    for key, sensor, x in (("gyro", "gyroscope", log.gyro), ("accel", "accelerometer", log.accel)):
        taus, adev = allan_deviation(x, rate)
        fits[key] = noise_from_allan(taus, adev, log.duration, names=[f"{sensor} {a}" for a in "xyz"])
        curves[key] = (taus, adev)
    noise = ImuNoise(
        accelerometer_noise_density=float(fits["accel"].noise_density.mean()),
        accelerometer_random_walk=float(fits["accel"].random_walk.mean()),
        gyroscope_noise_density=float(fits["gyro"].noise_density.mean()),
        gyroscope_random_walk=float(fits["gyro"].random_walk.mean()),
        update_rate=round(rate, 3),
    )
    # what was read and what weakens it, once the values are known (a refusal above is one line alone)
    for note in log.notes:
        info(f"{args.log}: {note}")
    for message in findings.messages():
        warn(COMMAND, f"{args.log}: {message}")
    write_text_atomic("--output", args.output, imu_yaml(noise, args.rostopic))
    if args.plot:
        taus = curves["gyro"][0]
        figure = allan_figure(
            taus.numpy(), curves["gyro"][1].numpy(), curves["accel"][1].numpy(),
            fits["gyro"].deviation(taus).numpy(), fits["accel"].deviation(taus).numpy(),
            {f"{key}_{part}": getattr(fits[key], attr).numpy() for key in ("gyro", "accel")
             for part, attr in (("white", "noise_density"), ("walk", "random_walk"))})
        written: list[str] = []
        if not write_png(args.plot, np.ascontiguousarray(figure), written):
            raise UserError(f"--plot {args.plot}: the figure could not be encoded")
    print("\n".join(summary_lines(args.log, log, rate, fits, noise)))
    return 0
