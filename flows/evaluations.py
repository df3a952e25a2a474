"""``multigrasp run --evaluate``: the pipeline's last step, every evaluation this config is missing, then the report.

The ``evaluate`` commands always write their results anew (a user asked for them; the execution evaluations serve
the lift jobs that finished before, :mod:`tasks.lift_jobs`).  After a whole ``run``, ``--evaluate`` runs only
those whose results under ``<workdir>/results/`` are not current for this config (:func:`flows.report.
evaluation_status`: made from this config's stage outputs now and under its settings), in the order of the paper's
tables, and ends with ``multigrasp report``.  A rerun after a crash or a Ctrl-C redoes only the evaluations that had
not written their file; a rerun with nothing changed computes nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from components.errors import MultigraspError
from flows.config import PipelineConfig


@dataclass(frozen=True)
class Evaluation:
    """One ``multigrasp evaluate`` invocation and the results files that make it current."""

    label: str
    files: tuple[str, ...]
    run: Callable[[PipelineConfig, str | None], object]
    """(config, the MLflow run to nest its run under) -> its report."""
    needs_ablations: bool = False
    """Current only if ``ablation_execution.json`` holds every ablation row (``evaluate execution --ablations``)."""


def planned_evaluations(ablations: bool) -> list[Evaluation]:
    """The evaluations of ``run --evaluate`` in the order of the paper's tables; with ``ablations`` the
    generator's and the execution's ablation variants too (each ablation specialist is trained: cached units)."""
    from flows.evaluate import evaluate_pregrasp
    from flows.evaluate_execution import evaluate_execution
    from flows.evaluate_curriculum import evaluate_curriculum
    from flows.evaluate_generalist import evaluate_generalist
    from flows.evaluate_generated_execution import evaluate_generated_execution

    generated = ("pregrasp_generated.json", "ablation_generator.json") if ablations else ("pregrasp_generated.json",)
    execution = ("execution.json", "ablation_execution.json") if ablations else ("execution.json",)
    return [
        Evaluation("evaluate pregrasp --source synthetic", ("pregrasp_synthetic.json",),
                   lambda cfg, parent: evaluate_pregrasp(cfg, "synthetic", parent_run_id=parent)),
        Evaluation("evaluate pregrasp --source generated" + (" --ablations" if ablations else ""), generated,
                   lambda cfg, parent: evaluate_pregrasp(cfg, "generated", ablations, parent)),
        Evaluation("evaluate execution" + (" --ablations" if ablations else ""), execution,
                   lambda cfg, parent: evaluate_execution(cfg, ablations, parent), needs_ablations=ablations),
        Evaluation("evaluate execution --source generated", ("execution_generated.json",),
                   evaluate_generated_execution),
        Evaluation("evaluate generalist", ("execution_generalist.json",), evaluate_generalist),
        *([Evaluation("evaluate curriculum", ("ablation_curriculum.json",), evaluate_curriculum)] if ablations else []),
    ]


def pending_evaluations(cfg: PipelineConfig, ablations: bool, finals: dict[str, str | None] | None = None,
                        planned: list[Evaluation] | None = None) -> list[tuple[Evaluation, str]]:
    """The ``planned`` evaluations (default :func:`planned_evaluations`) whose results are not current for ``cfg``,
    each with why (missing, stale, …)."""
    from flows.report import evaluation_status

    states = {row.name: row for row in evaluation_status(cfg, finals)}
    pending = []
    for evaluation in planned if planned is not None else planned_evaluations(ablations):
        reasons = [f"{name} {states[name].state}" for name in evaluation.files if states[name].state != "current"]
        if evaluation.needs_ablations and not reasons and not states["ablation_execution.json"].ablations:
            reasons.append("ablation_execution.json without the ablation specialists")
        if reasons:
            pending.append((evaluation, ", ".join(reasons)))
    return pending


def run_evaluations(cfg: PipelineConfig, ablations: bool, say: Callable[[str], None],
                    finals: dict[str, str | None] | None = None, parent_run_id: str | None = None):
    """Run every pending evaluation (:func:`pending_evaluations`), then write the report; returns it (None, with a
    line saying why, where another results file is unreadable) and how many evaluations were computed.  Their MLflow
    runs are children of ``parent_run_id`` (``run --evaluate``: the pipeline's run) when given."""
    import time

    from flows.report import write_report

    planned = planned_evaluations(ablations)
    pending = pending_evaluations(cfg, ablations, finals, planned)
    todo = {evaluation.label for evaluation, _ in pending}
    for evaluation in planned:
        if evaluation.label not in todo:
            say(f"[bold]evaluate[/] {evaluation.label[len('evaluate '):]}: current ({', '.join(evaluation.files)}), "
                "served from results/")
    for index, (evaluation, why) in enumerate(pending, 1):
        say(f"[bold]evaluate[/] {index}/{len(pending)} {evaluation.label[len('evaluate '):]} ({why})")
        start = time.perf_counter()
        evaluation.run(cfg, parent_run_id)
        say(f"[bold]evaluate[/] {index}/{len(pending)} done in {time.perf_counter() - start:.1f}s")
    try:
        return write_report(cfg.run.workdir, parent_run_id, cfg.tracking.experiment), len(pending)
    except MultigraspError as exc:  # another results file (an ablation's) unreadable: every evaluation is written
        say(f"[yellow]report not written:[/] {exc}")
        return None, len(pending)
