"""Compare two `multigrasp evaluate execution` runs pose by pose.

    python -m benchmarks.paired_execution A/results/execution/Syn-Pl/outcomes.json B/.../outcomes.json \
        [--column policy] [--column-b squeeze] [--json OUT]

Each ``outcomes.json`` lists the evaluated poses (``pose_key``: the seed key of its trials) with the successes of
each controller (``policy``; on Syn-Pl also ``w/o RL`` and ``squeeze``).  Two runs with the same
``specialists.eval_*`` settings lift the same poses with the same perturbations, so the difference of their success
is taken per pose and its standard error is over poses (the trials of one pose are not independent): a paired
comparison, much tighter than two separate rates.  ``--column-b`` compares another controller of B, e.g. run A's
policy against run B's squeeze; with one file, A's columns are compared with each other.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from components.errors import MultigraspError
from flows.paired import paired


def load_outcomes(path: Path) -> tuple[int, dict[int, dict]]:
    """(trials, pose_key -> row) of an outcomes.json; one-line error for a missing or foreign file."""
    try:
        data = json.loads(path.read_text())
        return int(data["trials"]), {int(row["pose_key"]): row for row in data["poses"]}
    except FileNotFoundError:
        raise MultigraspError(f"{path}: no such file; `multigrasp evaluate execution` writes "
                              "<workdir>/results/execution/<setting>/outcomes.json") from None
    except (ValueError, KeyError, TypeError) as exc:
        raise MultigraspError(f"{path}: not an evaluate-execution outcomes.json ({exc}); rerun the evaluation") from None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.paired_execution", description=__doc__.split("\n\n")[0])
    parser.add_argument("a", type=Path, help="outcomes.json of run A")
    parser.add_argument("b", type=Path, nargs="?", help="outcomes.json of run B (default: A itself)")
    parser.add_argument("--column", default="policy", help="controller of A (policy, w/o RL, squeeze)")
    parser.add_argument("--column-b", default=None, help="controller of B (default: --column)")
    parser.add_argument("--json", type=Path, default=None, help="also write the result here")
    args = parser.parse_args(argv)
    try:
        trials, a = load_outcomes(args.a)
        trials_b, b = load_outcomes(args.b) if args.b else (trials, a)
        if trials_b != trials:
            raise MultigraspError(f"A has {trials} trials per pose and B {trials_b}; compare evaluations with the "
                                  "same specialists.eval_trials")
        result = paired(a, b, args.column, args.column_b or args.column, trials)
    except MultigraspError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    result.update(a_file=str(args.a), b_file=str(args.b or args.a), column_a=args.column,
                  column_b=args.column_b or args.column)
    print(f"A {result['column_a']}: {100 * result['a']:.1f} %   B {result['column_b']}: {100 * result['b']:.1f} %   "
          f"B - A: {100 * result['difference']:+.1f} +- {100 * result['standard_error']:.1f} points "
          f"({result['poses']} poses x {trials} trials; poses higher / level / lower "
          f"{result['poses_higher']} / {result['poses_level']} / {result['poses_lower']})")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
