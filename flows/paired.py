"""Paired comparison of two evaluations of the same poses and seeded trials (``outcomes.json`` rows by pose key).

Two evaluations with the same ``specialists.eval_*`` settings lift the same poses with the same perturbations, so
their difference is taken per pose and its standard error is over poses (the trials of one pose are not
independent): much tighter than the difference of two separate rates.  Used by ``python -m
benchmarks.paired_execution`` and by the ablation tables that print a paired column (``evaluate curriculum``).
"""

from __future__ import annotations

import math

from components.errors import MultigraspError


def paired(a: dict[int, dict], b: dict[int, dict], column_a: str, column_b: str, trials: int) -> dict:
    """Success of each side on the poses both evaluated, and their paired difference (b - a) with its standard
    error over poses; ``a`` and ``b`` map a pose key to its outcomes row.  A one-line error with fewer than two
    shared poses."""
    keys = sorted(k for k in set(a) & set(b) if column_a in a[k] and column_b in b[k])
    if len(keys) < 2:
        raise MultigraspError(f"only {len(keys)} poses carry {column_a!r} in A and {column_b!r} in B; compare "
                              "evaluations of the same split with the same specialists.eval_* settings")
    ra = [a[k][column_a] / trials for k in keys]
    rb = [b[k][column_b] / trials for k in keys]
    d = [y - x for x, y in zip(ra, rb)]
    mean = sum(d) / len(d)
    se = math.sqrt(sum((v - mean) ** 2 for v in d) / (len(d) - 1) / len(d))
    return {"poses": len(keys), "trials": trials, "a": round(sum(ra) / len(ra), 4), "b": round(sum(rb) / len(rb), 4),
            "difference": round(mean, 4), "standard_error": round(se, 4),
            "poses_higher": sum(v > 0 for v in d), "poses_level": sum(v == 0 for v in d),
            "poses_lower": sum(v < 0 for v in d)}


def by_pose(outcomes: list[dict]) -> dict[int, dict]:
    """An evaluation's outcome rows (``SplitResult.outcomes``) by pose key."""
    return {int(row["pose_key"]): row for row in outcomes}


def paired_or_none(a: list[dict], b: list[dict], trials: int, column: str = "policy") -> dict | None:
    """:func:`paired` of two evaluations' outcome rows on ``column``; None where fewer than two poses are shared."""
    try:
        return paired(by_pose(a), by_pose(b), column, column, trials)
    except MultigraspError:
        return None


def paired_cell(result: dict | None) -> str:
    """``+0.9 ± 0.9`` (points, b - a) for a table; ``–`` without a comparison."""
    if result is None:
        return "–"
    return f"{100 * result['difference']:+.1f} ± {100 * result['standard_error']:.1f}"
