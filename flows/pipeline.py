"""The pipeline: stages in the order of the paper's figure, run, resumed and inspected.

Each stage module in ``flows/`` exposes ``STAGE``, ``UPSTREAM``, ``DESCRIPTION``,
``planned_units(cfg, upstream)`` (cache keys knowable now, for ``status``),
``runner_flow(cfg)`` (the Prefect flow bound to the configured task runner, called with
``(cfg, parent_run_id, upstream_manifests)`` — picklable inputs only, since process workers
receive the flow's parameters) and ``log_stage(tracker, result)``.  Later issues append their stages to :data:`STAGES`.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

from components.errors import MultigraspError
from flows import curriculum, distill, pointnet, reach, scenes, specialists, synthesize, train_generator
from flows.config import PipelineConfig
from flows.runtime import RunContext, StageResult, make_tracker, prefect_context
from tasks.artifacts import Manifest, lock_holder, lock_path, valid_manifest
from tasks.preflight import validate_inputs
from tasks.tracking import flatten

STAGES: tuple[ModuleType, ...] = (scenes, synthesize, train_generator, pointnet, specialists, reach, curriculum,
                                     distill)
"""Stage modules in execution order (generator, … are added by later issues)."""


def stage_names() -> list[str]:
    return [module.STAGE for module in STAGES]


def with_upstream(name: str) -> list[str]:
    """``name`` and every stage it needs, directly or not, in execution order (what a single-stage command runs:
    the upstream stages already done are served from cache)."""
    names = stage_names()
    if name not in names:
        raise MultigraspError(f"unknown stage '{name}' — stages are: {', '.join(names)}")
    needed, todo = set(), [name]
    while todo:
        stage = todo.pop()
        if stage not in needed:
            needed.add(stage)
            todo.extend(STAGES[names.index(stage)].UPSTREAM)
    return [stage for stage in names if stage in needed]


def select_stages(only: Sequence[str] | None = None, until: str | None = None) -> list[ModuleType]:
    """Stages to run: ``only`` (plus nothing else) or every stage up to ``until`` inclusive."""
    names = stage_names()
    for name in list(only or []) + ([until] if until else []):
        if name not in names:
            raise MultigraspError(f"unknown stage '{name}' — stages are: {', '.join(names)}")
    if only:
        return [m for m in STAGES if m.STAGE in only]
    if until:
        return list(STAGES[: names.index(until) + 1])
    return list(STAGES)


def _upstream_manifests(cfg: PipelineConfig, module: ModuleType, done: dict[str, Manifest]) -> dict[str, Manifest]:
    upstream = {}
    for name in module.UPSTREAM:
        if name in done:
            upstream[name] = done[name]
            continue
        found = stage_output(cfg, name)
        if found is None:
            raise MultigraspError(f"stage '{module.STAGE}' needs '{name}', which has not run for this config — "
                                  f"run `multigrasp run --until {name}` first")
        upstream[name] = found
    return upstream


def stage_output(cfg: PipelineConfig, name: str) -> Manifest | None:
    """The verified final manifest of a stage for this config, if it exists."""
    module = STAGES[stage_names().index(name)]
    upstream: dict[str, Manifest] = {}
    for up in module.UPSTREAM:
        found = stage_output(cfg, up)
        if found is None:
            return None
        upstream[up] = found
    specs = module.planned_units(cfg, upstream)
    if not specs:
        return None
    return valid_manifest(specs[-1].folder) if specs[-1].unit in ("merge", "stage") else None


def apply_torch_threads(threads: int) -> None:
    """``torch.set_num_threads`` for this process (0 = leave torch's default).

    Measured here (2 cores): when another busy thread or process shares the cores, torch's
    2-thread kernels stall on their barrier — FK of 1024 poses takes ~320 ms with 2 threads
    against ~30 ms with 1 (benchmarks/results/). With 2 parallel workers, use 1 thread each.
    """
    if threads:
        import torch

        torch.set_num_threads(threads)


def run_pipeline(cfg: PipelineConfig, modules: Sequence[ModuleType], command: str = "run") -> RunContext:
    """Run stages in order under one MLflow parent run; re-running resumes from the cache."""
    apply_torch_threads(cfg.run.torch_threads)
    validate_inputs(cfg.objects, cfg.hand, cfg.run.workdir)
    tracker = make_tracker(cfg)
    parent = tracker.start_run(f"{command}:{cfg.profile}", tags={"profile": cfg.profile, "command": command})
    tracker.log_params(parent, flatten(cfg.model_dump(mode="json")))
    ctx = RunContext(cfg=cfg, tracker=tracker, parent_run_id=parent)
    start = time.perf_counter()
    status = "FAILED"
    try:
        with prefect_context(cfg):
            for module in modules:
                upstream = _upstream_manifests(cfg, module, {k: r.manifest for k, r in ctx.results.items()})
                ctx.console.print(f"[bold]stage {module.STAGE}[/]: {module.DESCRIPTION}")
                t0 = time.perf_counter()
                result: StageResult = module.runner_flow(cfg)(cfg, parent, upstream)
                result.seconds = time.perf_counter() - t0
                _finish_stage_run(ctx, module, result)
                ctx.results[module.STAGE] = result
        status = "FINISHED"
    finally:
        total = time.perf_counter() - start
        tracker.log_metrics(parent, {"wall_s": total})
        tracker.end_run(parent, status)
        ctx.wall_s = total  # type: ignore[attr-defined]
    return ctx


def _finish_stage_run(ctx: RunContext, module: ModuleType, result: StageResult) -> None:
    tracker, run_id = ctx.tracker, result.run_id
    tags = {"cached": str(result.fully_cached).lower(), "units_executed": result.executed,
            "units_cached": result.cached, "manifest": str(Path(result.manifest.folder) / "manifest.json")}
    if result.fully_cached and result.manifest.producer_run_id:
        tags["cached_from_run"] = result.manifest.producer_run_id
    tracker.set_tags(run_id, tags)
    tracker.log_metrics(run_id, {"stage_wall_s": result.seconds})
    module.log_stage(tracker, result)
    tracker.end_run(run_id)
    how = "served from cache" if result.fully_cached else f"{result.executed} unit(s) computed, {result.cached} cached"
    ctx.console.print(f"[bold green]✓ {module.STAGE}[/] {how} in {result.seconds:.1f}s → {result.manifest.folder}")


# --------------------------------------------------------------------------- status


@dataclass
class StageStatus:
    name: str
    state: str          # done | partial | stale | missing | corrupt | blocked
    done_units: int
    known_units: int
    folder: str | None
    detail: str = ""


@dataclass
class StagePlan:
    """The units a stage of a config has now: their specs (cache keys and folders) and which of them verify.

    ``blocked_by`` names the upstream stages that are not done; such a stage has no specs, since its keys contain
    the upstream outputs' hashes."""

    module: ModuleType
    specs: list
    valid: list
    blocked_by: list[str]
    final: Manifest | None

    @property
    def started(self) -> bool:
        """Whether any planned unit has a folder (done, running, interrupted or altered) without the stage being
        done: a partial or corrupt stage, whose outputs may yet be completed or recomputed as they were."""
        return self.final is None and any(s.folder.is_dir() for s in self.specs)


def plan_stages(cfg: PipelineConfig, check=valid_manifest) -> list[StagePlan]:
    """Every stage of ``cfg`` in order with its planned units; ``check(folder)`` verifies a unit (a memoised
    :func:`valid_manifest` where several configs are planned over one work dir)."""
    plans: list[StagePlan] = []
    outputs: dict[str, Manifest | None] = {}
    for module in STAGES:
        blocked = [u for u in module.UPSTREAM if outputs.get(u) is None]
        if blocked:
            plans.append(StagePlan(module, [], [], blocked, None))
            outputs[module.STAGE] = None
            continue
        specs = module.planned_units(cfg, {u: outputs[u] for u in module.UPSTREAM})
        valid = [check(s.folder) for s in specs]
        final = valid[-1] if specs and specs[-1].unit in ("merge", "stage") else None
        outputs[module.STAGE] = final
        plans.append(StagePlan(module, specs, valid, [], final))
    return plans


def status(cfg: PipelineConfig) -> list[StageStatus]:
    """Which stages of this config are done, partial, stale, corrupt, missing or blocked."""
    rows: list[StageStatus] = []
    for plan in plan_stages(cfg):
        module, specs, valid, final = plan.module, plan.specs, plan.valid, plan.final
        if plan.blocked_by:
            rows.append(StageStatus(module.STAGE, "blocked", 0, 0, None, f"waits for {', '.join(plan.blocked_by)}"))
            continue
        corrupt = [s for s, v in zip(specs, valid) if v is None and (s.folder / "manifest.json").exists()]
        n_done = sum(v is not None for v in valid)
        # a planned unit's folder without a manifest: running now (its lock is held), or interrupted (a training
        # keeps its checkpoint)
        started_specs = [s for s, v in zip(specs, valid)
                         if v is None and s.folder.is_dir() and not (s.folder / "manifest.json").exists()]
        holders = [lock_holder(lock_path(cfg.run.workdir, s.key)) for s in started_specs]
        running = [h for h in holders if h is not None]
        started = len(started_specs)
        stage_dir = cfg.run.workdir / "stages" / module.STAGE
        others = [p for p in stage_dir.iterdir() if p.is_dir()] if stage_dir.exists() else []
        if final is not None:
            state, detail = "done", "served from cache"
        elif corrupt:
            state, detail = "corrupt", f"{len(corrupt)} unit(s) with missing/altered files will be recomputed"
        elif n_done or started:
            done_part = "finished units are kept; " if n_done else ""
            interrupted = started - len(running)
            started_part = "".join([
                f"{len(running)} unit(s) running now ({running[0]}); " if running else "",
                f"{interrupted} unit(s) interrupted (a training resumes from its last checkpoint); " if interrupted
                else ""])
            state, detail = "partial", f"{done_part}{started_part}the next run computes the rest"
        elif others:
            state, detail = "stale", ("outputs exist only for another config or code version (`multigrasp prune` "
                                      "lists them)")
        else:
            state, detail = "missing", ""
        rows.append(StageStatus(module.STAGE, state, n_done, len(specs),
                                final.folder if final else None, detail))
    return rows
