#!/bin/bash
# Forty-eighth session (README "Work directory, caching and resume", the ray runner): `multigrasp run --profile smoke
# --until synthesize` on fresh work dirs, 3 rounds of three alternated variants:
#   old      flows/runtime.py of commit 86725e5 (prefect-ray's own Ray per stage; a temporary Prefect server per worker)
#   new      the checkout's own flows/runtime.py (one Ray per invocation, the run's Prefect server for its workers)
#   threads  the default runner
# CHECKOUT: a clone of this repository whose .venv has the ray extra (`make install`, then
# `.venv/bin/pip install -e '.[ray]'`); its flows/runtime.py is swapped during the run and restored at the end.
# Writes OUTDIR/times.jsonl (one line per invocation), OUTDIR/<variant>_<round>.log and OUTDIR/times.json (medians).
#   run.sh CHECKOUT OUTDIR          (~5 min on 2 idle cores)
set -u
CHECKOUT=$(cd "${1:?usage: run.sh CHECKOUT OUTDIR}" && pwd); OUT=$(mkdir -p "${2:?usage: run.sh CHECKOUT OUTDIR}" && cd "$2" && pwd)
git -C "$CHECKOUT" show 86725e5:flows/runtime.py > "$OUT/runtime_old.py"
cp "$CHECKOUT/flows/runtime.py" "$OUT/runtime_new.py"
trap 'cp "$OUT/runtime_new.py" "$CHECKOUT/flows/runtime.py"' EXIT
cd "$CHECKOUT"
for rep in 1 2 3; do
  for v in old new threads; do
    if [ $v = threads ]; then cp "$OUT/runtime_new.py" flows/runtime.py; R=threads
    else cp "$OUT/runtime_$v.py" flows/runtime.py; R=ray; fi
    W="$OUT/work_${v}_$rep"; rm -rf "$W"
    s=$(date +%s.%N)
    timeout 900 .venv/bin/multigrasp run --profile smoke --runner $R --workdir "$W" --until synthesize > "$OUT/${v}_$rep.log" 2>&1
    rc=$?
    e=$(date +%s.%N)
    echo "{\"variant\": \"$v\", \"rep\": $rep, \"rc\": $rc, \"wall_s\": $(echo "$e - $s" | bc)}" >> "$OUT/times.jsonl"
    rm -rf "$W"
  done
done
.venv/bin/python - "$OUT" <<'PY'
import json, re, statistics, sys
from pathlib import Path
out = Path(sys.argv[1])
rows = [json.loads(line) for line in (out / "times.jsonl").read_text().splitlines()]
summary = {"runs": rows, "median_wall_s": {}, "median_stage_s": {}}
for v in ("old", "new", "threads"):
    summary["median_wall_s"][v] = round(statistics.median(r["wall_s"] for r in rows if r["variant"] == v), 1)
    stages = {"scenes": [], "synthesize": []}
    for log in sorted(out.glob(f"{v}_*.log")):
        for stage, seconds in stages.items():
            seconds.append(float(re.search(rf"✓ {stage} .* in ([0-9.]+)s", log.read_text()).group(1)))
    summary["median_stage_s"][v] = {k: statistics.median(x) for k, x in stages.items()}
(out / "times.json").write_text(json.dumps(summary, indent=1) + "\n")
print(summary["median_wall_s"], summary["median_stage_s"])
PY
