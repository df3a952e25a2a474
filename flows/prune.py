"""``multigrasp prune``: delete the unit folders of a work dir that no kept config uses any more.

Every unit folder is named by its cache key, so a config changed with ``--set``, another profile run in the same
work dir, or an upgrade of the components (their code version is part of every key) leaves the old folders behind:
``status`` shows such stages as ``stale``.  At paper scale they hold gigabytes.  A prune keeps every unit that the
kept configs plan now (:func:`flows.pipeline.plan_stages`): done, running, interrupted (a training's checkpoint)
or altered, and those of their ablation variants (the generator's and the specialists' overrides that ``evaluate
--ablations`` trains).  Everything else under ``stages/`` is a candidate, with its Prefect result record and its lock
file.

Two cases are kept whole.  A stage whose upstream stage of a kept config is partial or corrupt cannot say which of
its folders are current (their keys contain the upstream output's hash, which does not exist yet), so its folders
and those of the stages after it stay.  Folders under ``stages/`` that this version has no stage for stay too.
The lift jobs of ``evaluate execution`` (``stages/evaluate-execution/``, :mod:`tasks.lift_jobs`) and of ``evaluate
generalist`` (``stages/evaluate-generalist/``) go when they are of older code or unfinished; the finished ones of this code stay (:func:`_plan_lift_jobs`).

Without ``--yes`` nothing is deleted: the plan is printed.  With it, the work dir's lock is taken exclusively first
(:func:`tasks.artifacts.workdir_exclusive`), so a prune never deletes under a running ``run`` / ``evaluate`` /
``generate``; it stops with one line naming them instead.
"""

from __future__ import annotations

import shutil
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from components.errors import MultigraspError
from flows.config import PipelineConfig, with_overrides
from tasks.artifacts import lock_path, read_manifest, valid_manifest, workdir_exclusive
from tasks.generalist_jobs import STAGE as GENERALIST_JOBS
from tasks.lift_jobs import STAGE as LIFT_JOBS
from tasks.units import records_dir


@dataclass
class Candidate:
    """One unit folder no kept config uses."""

    stage: str
    key: str
    folder: Path
    bytes: int
    reason: str
    """``older code`` (made by another version of the stage's components), ``other config``, ``unfinished`` (no
    manifest: an interrupted unit of another config or version), or ``not used`` (the stage is blocked for every
    kept config, so the two cannot be told apart)."""


@dataclass
class PrunePlan:
    workdir: Path
    kept: list[str]
    """The configs whose units are kept, as labels (profile, file, overrides)."""
    candidates: list[Candidate] = field(default_factory=list)
    kept_units: dict[str, int] = field(default_factory=dict)
    """Per stage: unit folders kept."""
    guarded: dict[str, str] = field(default_factory=dict)
    """Stage → why all its folders are kept."""

    @property
    def bytes(self) -> int:
        return sum(c.bytes for c in self.candidates)


def ablation_variants(cfg: PipelineConfig) -> list[PipelineConfig]:
    """``cfg`` and the variants its ``evaluate --ablations`` trains (their units are kept with it)."""
    from flows.evaluate_execution import ABLATIONS
    from flows.evaluate_generated import GENERATOR_ABLATIONS

    overrides = [o for o in list(GENERATOR_ABLATIONS.values()) + list(ABLATIONS.values()) if o]
    return [cfg] + [with_overrides(cfg, o) for o in overrides]


def folder_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file() and not p.is_symlink())


def plan_prune(configs: Iterable[PipelineConfig], labels: list[str]) -> PrunePlan:
    """Which unit folders of the configs' work dir none of them (nor their ablation variants) uses."""
    from flows.pipeline import STAGES, plan_stages

    configs = list(configs)
    workdir = configs[0].run.workdir
    if any(c.run.workdir != workdir for c in configs):
        raise MultigraspError("the kept configs name different work dirs — prune one work dir at a time (--workdir)")
    if not (workdir / "stages").is_dir():
        raise MultigraspError(f"no work dir at {workdir} (no stages/ folder) — pass the --workdir to prune")
    memo: dict[Path, object] = {}

    def check(folder: Path):
        if folder not in memo:
            memo[folder] = valid_manifest(folder)
        return memo[folder]

    keep: set[tuple[str, str]] = set()
    guarded: dict[str, str] = {}
    codes: dict[str, set[str]] = {}
    for cfg in configs:
        for variant in ablation_variants(cfg):
            unsettled: set[str] = set()
            for plan in plan_stages(variant, check):
                name = plan.module.STAGE
                keep.update((name, s.key) for s in plan.specs)
                codes.setdefault(name, set()).update(s.code for s in plan.specs)
                upstream_unsettled = [u for u in plan.module.UPSTREAM if u in unsettled]
                if upstream_unsettled:
                    unsettled.add(name)
                    guarded.setdefault(name, f"{upstream_unsettled[0]} is partial or corrupt for a kept config, so "
                                             "which of its folders are current cannot be told yet")
                elif plan.started:
                    unsettled.add(name)
    known = {m.STAGE for m in STAGES}
    out = PrunePlan(workdir=workdir, kept=labels, guarded=guarded)
    for stage_dir in sorted(p for p in (workdir / "stages").iterdir() if p.is_dir()):
        name = stage_dir.name
        if name in (LIFT_JOBS, GENERALIST_JOBS):
            _plan_lift_jobs(stage_dir, out)
            continue
        if name not in known:
            out.guarded[name] = "no stage of this version has that name"
        for folder in sorted(p for p in stage_dir.iterdir() if p.is_dir()):
            if name not in known or name in guarded or (name, folder.name) in keep:
                out.kept_units[name] = out.kept_units.get(name, 0) + 1
                continue
            manifest = read_manifest(folder)
            if manifest is None:
                reason = "unfinished"
            elif not codes.get(name):
                reason = "not used"  # the stage is blocked for every kept config: no code version to compare
            elif manifest.code_version not in codes[name]:
                reason = "older code"
            else:
                reason = "other config"
            out.candidates.append(Candidate(name, folder.name, folder, folder_bytes(folder), reason))
    return out


def _plan_lift_jobs(stage_dir: Path, out: PrunePlan) -> None:
    """The lift jobs of the execution evaluations (:mod:`tasks.lift_jobs`, and the generalist's,
    :mod:`tasks.generalist_jobs`): those of older code, or unfinished (an interrupted job is lifted from its start
    again, so its folder holds nothing to resume), are candidates; the finished ones of this code stay whatever config
    made them (a few kB each, GIFs aside), so going back to a config evaluates it again from its jobs."""
    from tasks.artifacts import code_version
    from tasks.generalist_jobs import GENERALIST_LIFT_CODE
    from tasks.lift_jobs import LIFT_CODE

    current = code_version(*(LIFT_CODE if stage_dir.name == LIFT_JOBS else GENERALIST_LIFT_CODE))
    for folder in sorted(p for p in stage_dir.iterdir() if p.is_dir()):
        manifest = read_manifest(folder)
        reason = "unfinished" if manifest is None else "older code" if manifest.code_version != current else None
        if reason is None:
            out.kept_units[stage_dir.name] = out.kept_units.get(stage_dir.name, 0) + 1
        else:
            out.candidates.append(Candidate(stage_dir.name, folder.name, folder, folder_bytes(folder), reason))


def prune(configs: list[PipelineConfig], labels: list[str], delete: bool) -> tuple[PrunePlan, int]:
    """Plan a prune of the configs' work dir and, with ``delete``, carry it out; returns the plan and the bytes
    freed.  Deleting holds the work dir's lock exclusively from the plan to the last file, so no ``run`` /
    ``evaluate`` / ``generate`` runs meanwhile; if one runs now it stops with one line naming it."""
    if not delete:
        return plan_prune(configs, labels), 0
    workdir = configs[0].run.workdir
    if not (workdir / "stages").is_dir():
        return plan_prune(configs, labels), 0  # its one-line error
    with workdir_exclusive(workdir) as users:
        if users is not None:
            more = f" and {len(users) - 1} more" if len(users) > 1 else ""
            raise MultigraspError(f"an invocation is using {workdir} now ({users[0]}{more}) — nothing was deleted; "
                                  "prune when it has finished")
        plan = plan_prune(configs, labels)
        return plan, _delete(plan)


def _delete(plan: PrunePlan) -> int:
    """Delete the plan's folders, then the Prefect records and lock files no unit folder is left for (the caller
    holds the work dir's lock exclusively); returns the bytes freed."""
    freed = 0
    for c in plan.candidates:
        if c.folder.is_dir():
            shutil.rmtree(c.folder)
            freed += c.bytes
    stages = plan.workdir / "stages"
    for stage_dir in stages.iterdir():
        if stage_dir.is_dir() and not any(stage_dir.iterdir()):
            stage_dir.rmdir()
    # what no unit folder is left for: the deleted units' Prefect records and lock files, and the records of
    # finished invocations' flow results (Prefect names those by run id; nothing reads them once the run ended)
    units = {folder.name for folder in stages.glob("*/*") if folder.is_dir()}
    for record in records_dir(plan.workdir).glob("*"):
        if record.is_file() and record.name not in units:
            freed += record.stat().st_size
            record.unlink()
    for lock in lock_path(plan.workdir, "_").parent.glob("*.lock"):
        if _is_unit_key(lock.stem) and lock.stem not in units:
            lock.unlink()
    return freed


def _is_unit_key(name: str) -> bool:
    """Whether a lock file's name is a unit key (hex; the work dir's and MLflow's own locks have names)."""
    return bool(name) and all(ch in "0123456789abcdef" for ch in name)


def human_bytes(n: float) -> str:
    for unit in ("B", "KB", "MB", "GB"):
        if n < 1024 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} GB"


def plan_lines(plan: PrunePlan) -> list[str]:
    """The plan as text: the kept configs, one line per stage, the total."""
    lines = [f"work dir {plan.workdir}: keeping what these configs use now (with their ablation variants): "
             + "; ".join(plan.kept)]
    from flows.pipeline import stage_names

    present = {c.stage for c in plan.candidates} | set(plan.kept_units) | set(plan.guarded)
    stages = [s for s in stage_names() if s in present] + sorted(present - set(stage_names()))
    width = max([16, *map(len, stages)])
    for stage in stages:
        mine = [c for c in plan.candidates if c.stage == stage]
        reasons = {}
        for c in mine:
            reasons[c.reason] = reasons.get(c.reason, 0) + 1
        why = ", ".join(f"{n} {r}" for r, n in sorted(reasons.items()))
        line = (f"  {stage:<{width}} delete {len(mine):>3} ({human_bytes(sum(c.bytes for c in mine))}"
                f"{'; ' + why if why else ''}), keep {plan.kept_units.get(stage, 0)}")
        if stage in plan.guarded:
            line += f" — all kept: {plan.guarded[stage]}"
        lines.append(line)
    if not plan.candidates:
        lines.append("nothing to delete")
    return lines


__all__ = ["Candidate", "PrunePlan", "plan_prune", "prune", "plan_lines", "ablation_variants"]
