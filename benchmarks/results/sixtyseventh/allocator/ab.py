"""A/B of flows.runtime.apply_allocator on `bench generation` (sixty-seventh session).

Runs `run_generation_benchmark(repeats=3, threads=2)` in a fresh process per arm, alternating the arms
(allocator settings of RunConfig's defaults, or glibc's adaptive defaults), ROUNDS times, and writes every
run's JSON line to OUT.  Usage: python benchmarks/results/sixtyseventh/allocator/ab.py OUT [ROUNDS]
"""
import json
import subprocess
import sys

CHILD = """
import json, resource, sys
from flows.config import RunConfig
from flows.runtime import apply_allocator
applied = apply_allocator(RunConfig()) if sys.argv[1] == 'on' else {}
from benchmarks.generation import run_generation_benchmark
result = run_generation_benchmark(repeats=3, threads=2)
result['allocator'] = sys.argv[1]
result['applied'] = applied
result['minor_faults'] = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
print('RESULT ' + json.dumps(result))
"""

out, rounds = sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 3
with open(out, "a") as f:
    for r in range(rounds):
        for arm in (("on", "off") if r % 2 == 0 else ("off", "on")):
            text = subprocess.run([sys.executable, "-c", CHILD, arm], capture_output=True, text=True, check=True).stdout
            line = next(x for x in text.splitlines() if x.startswith("RESULT "))[7:]
            f.write(line + "\n"); f.flush()
            res = json.loads(line)
            print(arm, res["time_256_s"], res["sample_s"], res["ik_s"], res["refine_s"], res["minor_faults"], flush=True)
