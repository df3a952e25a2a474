"""Paired A/B of flows.runtime.apply_allocator on `bench generation` under the same machine state (sixty-seventh
session): both arms run at the same time, one process each with 1 torch thread on the 2 cores, so a slow period of
the shared machine slows both.  ROUNDS rounds of run_generation_benchmark(repeats=2, threads=1); every run's JSON line
goes to OUT.  Usage: python benchmarks/results/sixtyseventh/allocator/concurrent.py OUT [ROUNDS]
"""
import json
import subprocess
import sys
from pathlib import Path

CHILD = (Path(__file__).parent / "ab.py").read_text().split('CHILD = """')[1].split('"""')[0].replace(
    "repeats=3, threads=2", "repeats=2, threads=1")

out, rounds = sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 3
with open(out, "a") as f:
    for r in range(rounds):
        procs = {arm: subprocess.Popen([sys.executable, "-c", CHILD, arm], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                       text=True) for arm in ("on", "off")}
        for arm, proc in procs.items():
            text, _ = proc.communicate()
            line = next(x for x in text.splitlines() if x.startswith("RESULT "))[7:]
            res = json.loads(line)
            res["round"] = r
            f.write(json.dumps(res) + "\n"); f.flush()
            print(r, arm, res["time_256_s"], res["sample_s"], res["ik_s"], res["refine_s"], res["minor_faults"], flush=True)
