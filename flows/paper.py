"""The paper's published figures (Li et al., RA-L 2024, "MultiGrasp"), for comparison beside every result table.

One place for them: ``evaluate`` puts them in a ``paper`` column (and a ``paper`` field of the JSON rows), and
``multigrasp report`` sets a work dir's results beside all of them.  Table I is "Quantitative evaluations"
(pre-grasp quality of synthesised and generated grasps, and execution success); Table II is "Ablation studies"
(a: the generative model, b: specialist settings in RL, c: training settings in RL).

Read the ablation bases with care: the paper's Table II(b) and II(c) are not measured on Syn-Pl.  II(b)'s
``Ours`` (40.20 %) is Table I's Gen-Pl specialists; II(c)'s ``Ours*`` (45.25 %) is on "a subset of objects".
The execution figures of Table I are the state-based specialists'; the vision-based generalist's, after the slash in
the paper, are in :data:`PAPER_GENERALIST` (the paper gives them for Syn-Pl and Gen-Pl only).
"""

from __future__ import annotations

from typing import Any


def number_cell(value: Any, digits: int) -> str:
    """A table cell: ``value`` with ``digits`` decimals, or "–" for a figure that is not there."""
    return "–" if value is None else f"{value:.{digits}f}"


#: Table I, pre-grasp columns: Q1 (min over objects), PN (mm), Div (deg), time (s per 256 grasps; the synthesis
#: row's "≈ 1000" is its rough total).
PAPER_PREGRASP: dict[str, dict[str, float]] = {
    "Syn-Pl": {"q1": 0.30, "pn_mm": 1.64, "div_deg": 8.54},
    "Syn-Com": {"q1": 0.31, "pn_mm": 1.78, "div_deg": 8.58},
    "Syn-Geo": {"q1": 0.31, "pn_mm": 1.81, "div_deg": 8.66},
    "Gen-Pl": {"q1": 0.29, "pn_mm": 1.67, "div_deg": 9.24, "time_256_s": 12.28},
    "Gen-Com": {"q1": 0.25, "pn_mm": 2.65, "div_deg": 8.45, "time_256_s": 12.83},
    "Gen-Geo": {"q1": 0.29, "pn_mm": 1.54, "div_deg": 9.14, "time_256_s": 12.08},
}

#: Table I, execution: the state-based specialists' success (fraction; all objects above 10 cm, 5 trials per pose).
PAPER_EXECUTION: dict[str, float] = {
    "Syn-Pl": 0.6834, "Syn-Com": 0.2673, "Syn-Geo": 0.2255,
    "Gen-Pl": 0.4020, "Gen-Com": 0.2332, "Gen-Geo": 0.1565,
}

#: Table I, execution: the vision-based generalist's success (after the slash; the paper gives no other setting's).
PAPER_GENERALIST: dict[str, float] = {"Syn-Pl": 0.4413, "Gen-Pl": 0.3024}

#: Table II(a), the generative model (Gen-Pl): Q1, PN (mm) and the execution success (fraction).
PAPER_GENERATOR_ABLATIONS: dict[str, dict[str, float]] = {
    "Ours": {"q1": 0.29, "pn_mm": 1.67, "succ": 0.4020},
    "Joint Angles": {"q1": 0.18, "pn_mm": 5.50, "succ": 0.1931},
    "w/o Obj Embd": {"q1": 0.27, "pn_mm": 1.38, "succ": 0.3721},
    "w/o Refinement": {"q1": 0.29, "pn_mm": 7.68, "succ": 0.1624},
}

#: Table II(b) and II(c), execution ablations (fraction), with the base each is measured against.
PAPER_EXECUTION_ABLATIONS: dict[str, dict[str, Any]] = {
    "w/o RL": {"succ": 0.0137, "base": "Table II(c): Ours* 45.25 % on a subset of objects"},
    "w/o Goal": {"succ": 0.1679, "base": "Table II(c): Ours* 45.25 % on a subset of objects"},
    "w/o Spe-Pl": {"succ": 0.2909, "base": "Table II(b): Ours 40.20 % (the Gen-Pl specialists)"},
    "w/o Spe-Com": {"succ": 0.2623, "base": "Table II(b): Ours 40.20 % (the Gen-Pl specialists)"},
    "w/o Spe": {"succ": 0.3734, "base": "Table II(b): Ours 40.20 % (the Gen-Pl specialists)"},
}


#: Table II(c), the adaptation rows (fraction): the paper's Ours* is measured "on a subset of objects".
PAPER_CURRICULUM_ABLATIONS: dict[str, float] = {"Ours (curriculum)": 0.4525, "w/o Adpt": 0.2505, "w/o Curr": 0.2488}


def curriculum_paper(setting: str) -> float | None:
    """The paper's Table II(c) figure for a row of ``evaluate curriculum`` (its Ours* for ours)."""
    return PAPER_CURRICULUM_ABLATIONS.get(setting)


def pregrasp_paper(setting: str) -> dict[str, float] | None:
    """The paper's Table I pre-grasp figures for a row of ``evaluate pregrasp`` (None where it has none)."""
    return PAPER_PREGRASP.get(setting)


def execution_paper(setting: str) -> float | None:
    """The paper's success for a row of ``evaluate execution`` or its ablation table (None where it has none)."""
    if setting in PAPER_EXECUTION:
        return PAPER_EXECUTION[setting]
    if setting in PAPER_EXECUTION_ABLATIONS:
        return PAPER_EXECUTION_ABLATIONS[setting]["succ"]
    return None


def generalist_paper(setting: str) -> float | None:
    """The paper's generalist success for a setting (None where it gives none)."""
    return PAPER_GENERALIST.get(setting)
