#!/usr/bin/env bash
# The long budget: the rl experiment alone at the paper's 10^7 agent steps on MinAtar's five games,
# 3 seeds, A2C, RAPL-A2C and RAPL-A2C as the authors' code (45 runs), into SWEEP with JOBS runs at a
# time; 14.5 run-hours as run on a 2-core CPU in 2026-12 (about 8 h with 2 jobs; the estimate from
# the cpu budget's run times ×10 was 30). Rerun the same command to continue after a kill, a reboot
# or on a new machine: finished runs are skipped and the others resume from their last checkpoint
# (one every 10^6 steps), losing at most that. A SWEEP that does not exist yet starts as a copy of
# the committed snapshot (bench/results/experiments/long) where there is one. It runs under `nice`
# (NICE, 10 unless set) so the machine stays usable, each run on one thread (the sweep passes
# --torch-threads 1; the thread variables below keep NumPy's BLAS to one too). Then report and
# snapshot it:
#
#     nohup bench/sweep_long.sh /work/sweeps/long 2 > /work/sweeps/long.log 2>&1 &
#     .venv/bin/routine-gym experiment report /work/sweeps/long          # any time, also while it runs
#     .venv/bin/python bench/snapshot_experiments.py /work/sweeps/long bench/results/experiments/long \
#         --command "bench/sweep_long.sh SWEEP 2" --beside bench/results/experiments/cpu
set -euo pipefail
SWEEP=${1:?usage: bench/sweep_long.sh SWEEP [JOBS]}
JOBS=${2:-2}
# The clone's venv (`make run` or `make test` makes it), else python3 (Debian has no `python`).
REPO="$(cd "$(dirname "$0")/.." && pwd)"
if [ -z "${PYTHON:-}" ]; then
  if [ -x "$REPO/.venv/bin/python" ]; then PYTHON="$REPO/.venv/bin/python"; else PYTHON=python3; fi
fi
NICE=${NICE:-10}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1} MKL_NUM_THREADS=${MKL_NUM_THREADS:-1}
SNAPSHOT="$(cd "$(dirname "$0")" && pwd)/results/experiments/long"
if [ ! -e "$SWEEP" ] && [ -d "$SNAPSHOT/runs" ]; then
  echo "starting $SWEEP from the snapshot $SNAPSHOT"
  mkdir -p "$(dirname "$SWEEP")"
  cp -r "$SNAPSHOT" "$SWEEP"
fi
echo "=== $(date -u +%FT%TZ) rl --budget long, $JOBS at a time, nice $NICE"
nice -n "$NICE" "$PYTHON" -m routine_gym.cli experiment run rl --budget long --out "$SWEEP" \
  --jobs "$JOBS"
echo "=== $(date -u +%FT%TZ) rl --budget long finished"
