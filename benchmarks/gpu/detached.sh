#!/usr/bin/env bash
# Work longer than one 10-minute device call, run detached (setsid) on a machine kept warm by back-to-back calls:
#   bash benchmarks/gpu/detached.sh start "JOB" ["JOB" ...]  # each JOB a shell command, run one after another
#   bash benchmarks/gpu/detached.sh wait [SECONDS]            # follows the log until all ended or SECONDS passed
# The jobs run in a copy of the checkout (/tmp/detached/repo) with OUT=/tmp/detached/out; `wait` copies its files
# (the *.json and *.log, then stability folders' reports gathered into stability_partial_RUN.json) to the call's $OUT. The calls must follow each other within
# the machine's idle release (30 s), or it is given back and the jobs end with it.
set -uo pipefail
cd "$(dirname "$0")/../.."
D=/tmp/detached
case "${1:?start|wait}" in
  start)
    shift; mkdir -p $D/out; rm -f $D/done
    printf '%s\n' "$@" > $D/jobs
    # The jobs run in a copy of the checkout: every device call syncs the checkout again, which removes what a job
    # built or wrote inside it (a gsplat build in .gsplat_build/ vanished under twelve running trainings) and
    # leaves a running process in a deleted working directory.
    rm -rf $D/repo; mkdir -p $D/repo; cp -a . $D/repo/
    setsid nohup bash -c "cd $D/repo; export OUT=$D/out; while IFS= read -r job; do echo \"[\$(date +%T)] \$job\"; bash -c \"\$job\";
      echo \"[\$(date +%T)] rc \$?\"; done < $D/jobs; touch $D/done" > $D/log 2>&1 < /dev/null &
    echo "started: $(wc -l < $D/jobs) jobs, log $D/log"
    ;;
  wait)
    if [ ! -f $D/log ]; then  # a fresh machine: the one that ran `start` went back, and its jobs ended with it
      echo "no $D/log: this machine never ran \`start\` (the machine that did was given back); start again" >&2
      exit 3
    fi
    T0=$(date +%s) seen=0
    while :; do
      n=$(wc -l < $D/log); [ "$n" -gt "$seen" ] && { sed -n "$((seen + 1)),${n}p" $D/log | cut -c1-300; seen=$n; }
      [ -f $D/done ] && { echo "all jobs ended"; break; }
      [ $(( $(date +%s) - T0 )) -ge "${2:-560}" ] && { echo "still running after ${2:-560} s"; break; }
      sleep 5
    done
    python3 - "$D/out" <<'PY'
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
for st in Path("/tmp").glob("ms*/*/stability"):
    rows = []
    for rep in sorted(st.glob("*/report.json")):
        try:
            m = json.loads(rep.read_text())["mass"]
            rows.append({"setting": rep.parent.name, "mean_kg": m["mean_kg"], "volume_m3": m["volume_m3"]})
        except Exception as e:  # an export still writing
            rows.append({"setting": rep.parent.name, "error": str(e)})
    (out / f"stability_partial_{st.parent.parent.name}_{st.parent.name}.json").write_text(json.dumps(rows, indent=1))
PY
    cp -r $D/out/. "${OUT:-.}/" 2>/dev/null; cp $D/log "${OUT:-.}/detached.log"
    rm -f "${OUT:-.}/gpu.txt"; ls "${OUT:-.}"
    ;;
esac
