"""Paired A/B of two code trees on `bench generation` and `bench synthesis` (sixty-eighth session: the self-collision
screen).  Both arms run at the same time, one process each with 1 torch thread on the 2 cores, so a slow period of
the shared machine slows both; the allocator settings of RunConfig's defaults are applied in both.
Usage: python concurrent.py OUT ROUNDS TREE_A TREE_B   (TREE: a checkout of the repository; A = the change)
Each round runs run_generation_benchmark(repeats=2, threads=1), then run_synthesis_benchmark(repeats=1, threads=1,
steps_scale=0.1); every run's JSON line goes to OUT with its arm and round.
"""
import json
import subprocess
import sys

CHILD = """
import json, sys
sys.path.insert(0, sys.argv[1])
from flows.config import RunConfig
from flows.runtime import apply_allocator
apply_allocator(RunConfig())
if sys.argv[2] == 'generation':
    from benchmarks.generation import run_generation_benchmark
    result = run_generation_benchmark(repeats=2, threads=1)
else:
    from benchmarks.synthesis import run_synthesis_benchmark
    result = run_synthesis_benchmark(repeats=1, threads=1, steps_scale=0.1)
print('RESULT ' + json.dumps(result))
"""

out, rounds, trees = sys.argv[1], int(sys.argv[2]), {"A": sys.argv[3], "B": sys.argv[4]}
with open(out, "a") as f:
    for r in range(rounds):
        for bench in ("generation", "synthesis"):
            procs = {arm: subprocess.Popen([sys.executable, "-c", CHILD, tree, bench], cwd=tree, stdout=subprocess.PIPE,
                                           stderr=subprocess.DEVNULL, text=True) for arm, tree in trees.items()}
            for arm, proc in procs.items():
                text, _ = proc.communicate()
                line = next(x for x in text.splitlines() if x.startswith("RESULT "))[7:]
                res = dict(json.loads(line), arm=arm, round=r, bench=bench)
                f.write(json.dumps(res) + "\n"); f.flush()
                keys = ("time_256_s", "sample_s", "ik_s", "refine_s") if bench == "generation" else ("step_ms", "fk_ms", "accepted_per_s")
                print(r, bench, arm, *[res.get(k) for k in keys], flush=True)
