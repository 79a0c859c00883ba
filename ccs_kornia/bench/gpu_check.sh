#!/usr/bin/env bash
# The GPU path proven in one call, under 6 minutes on a GPU machine:
#   device-parametrised tests on CUDA, CPU-vs-GPU corners (<= 1e-3 px) and calibrations (<= 1e-6 relative),
#   CUDA synchronisations per call, detection images/s at batch 1/16/64, calibrations/s at 1/64/256 cameras;
#   with two GPUs, calibrate-many on 2 GPUs (DDP) against 1 GPU: the same lines, each set once, both wall times.
# Without CUDA it is a dry run: it says what it would check and runs the CPU half.
#   ccs_kornia/bench/gpu_check.sh [--dry-run] [--no-tests] [--out report.json]
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_WAIT_POLICY="${OMP_WAIT_POLICY:-PASSIVE}"
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
exec python -m ccs_kornia.bench.gpu_check "$@"
