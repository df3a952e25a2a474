"""Paired A/B of flows.runtime.apply_allocator on `bench synthesis` (its MALA step and FK medians; sixty-seventh
session): both arms at the same time, one process each with 1 torch thread, steps scaled by STEPS_SCALE.
Usage: python benchmarks/results/sixtyseventh/allocator/concurrent_synthesis.py OUT [ROUNDS] [STEPS_SCALE]
"""
import json
import subprocess
import sys

CHILD = """
import json, resource, sys
from flows.config import RunConfig
from flows.runtime import apply_allocator
applied = apply_allocator(RunConfig()) if sys.argv[1] == 'on' else {}
from benchmarks.synthesis import run_synthesis_benchmark
result = run_synthesis_benchmark(repeats=3, threads=1, steps_scale=float(sys.argv[2]))
result['allocator'] = sys.argv[1]
result['minor_faults'] = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
print('RESULT ' + json.dumps(result))
"""

out = sys.argv[1]
rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 2
scale = sys.argv[3] if len(sys.argv) > 3 else "0.1"
with open(out, "a") as f:
    for r in range(rounds):
        procs = {arm: subprocess.Popen([sys.executable, "-c", CHILD, arm, scale], stdout=subprocess.PIPE,
                                       stderr=subprocess.DEVNULL, text=True) for arm in ("on", "off")}
        for arm, proc in procs.items():
            text, _ = proc.communicate()
            res = json.loads(next(x for x in text.splitlines() if x.startswith("RESULT "))[7:])
            res["round"] = r
            f.write(json.dumps(res) + "\n"); f.flush()
            print(r, arm, {k: res.get(k) for k in ("step_ms", "fk_ms", "accepted_per_s", "minor_faults")}, flush=True)
