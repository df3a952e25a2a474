"""How long ``multigrasp ui`` takes to answer, and to serve a burst of requests, with N MLflow server workers.

    python -m benchmarks.ui_start --workdir runs --workers 4 2 1 --repeats 3 --json OUT

For each worker count, ``--repeats`` times: start ``multigrasp ui --workers N`` on a free port, time until the
REST API answers an experiment search (``start_s``: what a user waits for after the command), wait ``--settle``
seconds for the other workers to finish starting, then time ``--burst`` run searches of up to 100 runs each sent
by 16 threads at once (``burst_s``: the UI's tables load runs in parallel requests).  Medians per worker count. The
work dir must hold an MLflow store (``multigrasp run`` makes one).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import time
import urllib.request
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

HOST = "127.0.0.1"


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind((HOST, 0))
        return sock.getsockname()[1]


def _post(port: int, path: str, body: dict, timeout: float) -> int:
    request = urllib.request.Request(f"http://{HOST}:{port}/api/2.0/mlflow/{path}", data=json.dumps(body).encode(),
                                     headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=timeout) as response:
        return len(response.read())


def _experiment_ids(port: int) -> list[str]:
    with urllib.request.urlopen(f"http://{HOST}:{port}/api/2.0/mlflow/experiments/search?max_results=100",
                                timeout=60) as response:
        return [e["experiment_id"] for e in json.loads(response.read()).get("experiments", [])]


def measure(workdir: Path, workers: int, settle: float, burst: int, deadline_s: float) -> dict:
    """One start of ``multigrasp ui --workers workers``: ``start_s`` and ``burst_s``."""
    port = _free_port()
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "flows.cli", "ui", "--workdir", str(workdir), "--port", str(port),
                             "--workers", str(workers)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        while True:
            try:
                ids = _experiment_ids(port)
                break
            except OSError:
                if proc.poll() is not None:
                    raise SystemExit(f"multigrasp ui --workers {workers} exited ({proc.returncode}) before answering")
                if time.perf_counter() - start > deadline_s:
                    raise SystemExit(f"multigrasp ui --workers {workers} did not answer within {deadline_s} s")
                time.sleep(0.1)
        start_s = time.perf_counter() - start
        time.sleep(settle)
        body = {"experiment_ids": ids, "max_results": 100}
        begin = time.perf_counter()
        with ThreadPoolExecutor(16) as pool:
            sizes = list(pool.map(lambda _: _post(port, "runs/search", body, 120), range(burst)))
        return {"start_s": round(start_s, 2), "burst_s": round(time.perf_counter() - begin, 2),
                "response_bytes": sizes[0]}
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=60)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workdir", type=Path, required=True, help="a work dir with an MLflow store")
    parser.add_argument("--workers", type=int, nargs="+", default=[4, 2, 1], help="worker counts to compare")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--settle", type=float, default=15.0, help="seconds between the answer and the burst")
    parser.add_argument("--burst", type=int, default=32, help="run searches sent at once")
    parser.add_argument("--deadline", type=float, default=300.0, help="seconds to wait for an answer")
    parser.add_argument("--json", type=Path, required=True)
    args = parser.parse_args(argv)
    if not (args.workdir / "mlflow.db").is_file():
        raise SystemExit(f"no MLflow store in {args.workdir} — run `multigrasp run` there first")
    rows = {}
    for workers in args.workers:
        runs = [measure(args.workdir, workers, args.settle, args.burst, args.deadline) for _ in range(args.repeats)]
        rows[str(workers)] = {"start_s": statistics.median(r["start_s"] for r in runs),
                              "burst_s": statistics.median(r["burst_s"] for r in runs), "runs": runs}
        print(f"{workers} workers: answers after {rows[str(workers)]['start_s']} s, {args.burst} run searches in "
              f"{rows[str(workers)]['burst_s']} s (medians of {args.repeats})", flush=True)
    result = {"workers": rows, "cpu_count": os.cpu_count(), "burst": args.burst, "settle_s": args.settle,
              "repeats": args.repeats}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
