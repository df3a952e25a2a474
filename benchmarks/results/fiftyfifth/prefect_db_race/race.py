"""Two `multigrasp run --profile smoke` at once on a fresh PREFECT_HOME and work dir (as
tests/test_resume.py::test_two_invocations...), N times (`python benchmarks/results/fiftyfifth/prefect_db_race/race.py N`); saves the outputs of any pair that printed a traceback."""
import os, subprocess, sys, tempfile
from pathlib import Path
ROOT = Path(__file__).resolve().parents[4]  # the checkout
sys.path.insert(0, str(ROOT))
import tasks  # noqa: F401  the project's Prefect env defaults, as in the test process
from tests.test_flows import SMALL

n = int(sys.argv[1])
bad = 0
for k in range(n):
    home, work = tempfile.mkdtemp(), tempfile.mkdtemp()
    env = {**os.environ, "PREFECT_HOME": home}
    argv = [sys.executable, "-m", "flows.cli", "run", "--profile", "smoke", "--workdir", work + "/runs"]
    for item in SMALL:
        argv += ["--set", item]
    procs = [subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=ROOT) for _ in range(2)]
    outs = [p.communicate(timeout=600)[0] for p in procs]
    tb = any("Traceback" in o for o in outs)
    bad += tb
    print(k, [p.returncode for p in procs], "TRACEBACK" if tb else "clean", work, flush=True)
    if tb:
        for i, o in enumerate(outs):
            (Path(__file__).parent / f"out{k}_{i}.txt").write_text(o)
print("tracebacks", bad, "of", n)
