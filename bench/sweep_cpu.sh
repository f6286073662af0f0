#!/usr/bin/env bash
# The cpu budget of the seven experiments, one whole experiment after another (diagnosis first),
# into SWEEP; rerun the same command to continue after a kill or on a new machine. A SWEEP that does
# not exist yet starts as a copy of the committed snapshot (bench/results/experiments/cpu), so
# runs finished in earlier sessions are not redone. Then snapshot it:
#
#     bench/sweep_cpu.sh /work/sweeps/cpu 2
#     .venv/bin/python bench/snapshot_experiments.py /work/sweeps/cpu bench/results/experiments/cpu \
#         --command "bench/sweep_cpu.sh SWEEP 2"
set -euo pipefail
SWEEP=${1:?usage: bench/sweep_cpu.sh SWEEP [JOBS]}
JOBS=${2:-2}
# The clone's venv (`make run` or `make test` makes it), else python3 (Debian has no `python`).
REPO="$(cd "$(dirname "$0")/.." && pwd)"
if [ -z "${PYTHON:-}" ]; then
  if [ -x "$REPO/.venv/bin/python" ]; then PYTHON="$REPO/.venv/bin/python"; else PYTHON=python3; fi
fi
BUDGET=${BUDGET:-cpu}  # BUDGET=smoke tries the script in seconds
SNAPSHOT="$(cd "$(dirname "$0")" && pwd)/results/experiments/$BUDGET"
if [ ! -e "$SWEEP" ] && [ -d "$SNAPSHOT/runs" ]; then
  echo "starting $SWEEP from the snapshot $SNAPSHOT"
  mkdir -p "$(dirname "$SWEEP")"
  cp -r "$SNAPSHOT" "$SWEEP"
fi
for NAME in diagnosis rl curves coinrun ablation imitation scalability; do
  echo "=== $(date -u +%FT%TZ) $NAME"
  "$PYTHON" -m routine_gym.cli experiment run "$NAME" --budget "$BUDGET" --out "$SWEEP" --jobs "$JOBS"
done
echo "=== $(date -u +%FT%TZ) all seven finished"
