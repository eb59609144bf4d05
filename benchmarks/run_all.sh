#!/usr/bin/env bash
# Every benchmark, one after another, alone on an idle machine; then RESULTS.md is reassembled.
#
#   benchmarks/run_all.sh            # the sizes the issues ask for (about 3 hours on 2 cores)
#   BENCH_PROFILE=short benchmarks/run_all.sh   # fewer seeds/trials (about 1 hour), same scripts
#   BENCH_ONLY="localize_sim env" benchmarks/run_all.sh   # a subset, by results-file name
#   BENCH_AB_BASE=e054b11 BENCH_ONLY=localize_ab benchmarks/run_all.sh   # old vs new, alternated
#
# Each script writes benchmarks/results/<name>.md with its provenance lines (commit, date,
# load average before that script started, command), so a reader sees what a short profile
# left out. The run refuses to start while the 1-minute load average is >= 1 (wait for the
# machine to go idle; BENCH_FORCE=1 runs anyway and each table is then flagged BUSY). Between
# scripts it waits (up to 5 minutes) for the previous script's load to fall below 1.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
PROFILE=${BENCH_PROFILE:-full}
ONLY=${BENCH_ONLY:-spg localize localize_sim localize_ab freeform env grasp objects objects_localization bin backends grasp_synthesis}
R=benchmarks/results

load=$(cut -d' ' -f1 /proc/loadavg)
if [ "${BENCH_FORCE:-0}" != 1 ] && awk "BEGIN{exit !($load >= 1.0)}"; then
  echo "run_all: load average $load >= 1: the machine is busy; wait, or BENCH_FORCE=1" >&2
  exit 2
fi

# the peers come from the bench extra; a missing one turns its rows into "unavailable"
if ! $PY -c "import sklearn, open3d, cv2, gymnasium_robotics" 2>/dev/null && [ "${BENCH_FORCE:-0}" != 1 ]; then
  echo "run_all: a peer library is missing: install the bench extra (make bench, or $PY -m pip install -e '.[bench]')" >&2
  exit 2
fi

if [ "$PROFILE" = short ]; then
  SIM_N=50; FF_TRIALS=4; GRASP_EP=15; ENV_EP=20; OBJ_N=4; BIN_N=4; BACK_EP=12
else
  SIM_N=100; FF_TRIALS=4; GRASP_EP=100; ENV_EP=100; OBJ_N=50; BIN_N=20; BACK_EP=24
fi
# any size can be set alone, e.g. BENCH_OBJ_N=20 BENCH_PROFILE=short benchmarks/run_all.sh
SIM_N=${BENCH_SIM_N:-$SIM_N}; GRASP_EP=${BENCH_GRASP_EP:-$GRASP_EP}; OBJ_N=${BENCH_OBJ_N:-$OBJ_N}
ENV_EP=${BENCH_ENV_EP:-$ENV_EP}
OBJ_NF=${BENCH_OBJ_NF:-$OBJ_N}  # objects with the range finder failed (stereo grasps: 40-90 s)
BIN_N=${BENCH_BIN_N:-$BIN_N}; BACK_EP=${BENCH_BACK_EP:-$BACK_EP}
BIN_NF=${BENCH_BIN_NF:-$BIN_N}  # bins cleared with the range finder failed (2-3x a healthy bin)

settle() {  # wait (up to 5 min) for the previous script's load to decay below 1
  local i=0 l
  while [ "${BENCH_FORCE:-0}" != 1 ] && [ $i -lt 60 ]; do
    l=$(cut -d' ' -f1 /proc/loadavg)
    awk "BEGIN{exit !($l < 1.0)}" && return 0
    sleep 5; i=$((i + 1))
  done
}

run() {  # name, command...
  local name=$1; shift
  case " $ONLY " in *" $name "*) ;; *) return 0 ;; esac
  settle
  echo "== $name: $* (load $(cut -d' ' -f1-3 /proc/loadavg))" >&2
  local t0=$SECONDS
  "$@"
  echo "== $name done in $((SECONDS - t0)) s" >&2
}

run spg $PY benchmarks/spg.py --large
run localize $PY benchmarks/localize.py --trials 4
run localize_sim $PY benchmarks/localize_sim.py --n $SIM_N --no-progress --out $R/localize_sim.md
# the old and the new code alternated (needs a base commit: BENCH_AB_BASE=<rev>)
if [ -n "${BENCH_AB_BASE:-}" ]; then
  run localize_ab $PY benchmarks/localize_ab.py --base "$BENCH_AB_BASE"
fi
run freeform $PY benchmarks/freeform.py --trials $FF_TRIALS --cv-contrib venv  # the bench extra's cv2 is the contrib build
run env $PY benchmarks/env.py
run grasp $PY benchmarks/grasp.py --episodes $GRASP_EP --env-episodes $ENV_EP --workers 2
run objects $PY benchmarks/objects.py --n $OBJ_N --n-failed $OBJ_NF --workers 2 --out $R/objects.md
run objects_localization $PY benchmarks/objects.py --n $OBJ_N --no-grasp --workers 2 --out $R/objects_localization.md  # both modes over --n seeds
run bin $PY benchmarks/bin.py --n $BIN_N --n-failed $BIN_NF --workers 2 --out $R/bin.md
run backends $PY benchmarks/backends.py --episodes $BACK_EP --out $R/backends.md
run grasp_synthesis $PY benchmarks/grasp_synthesis.py
$PY benchmarks/collect_results.py
