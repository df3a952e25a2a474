"""``multigrasp`` — the command line of the pipeline.

    multigrasp run --profile smoke              # every stage, end to end (resumes from cache)
    multigrasp run --profile bench --until scenes
    multigrasp status --profile smoke           # done / partial / stale / corrupt / missing per stage
    multigrasp stages                           # the stage DAG
    multigrasp scenes --profile smoke           # only the scenes stage
    multigrasp synthesize --profile smoke       # only the synthesize stage (scenes must be done)
    multigrasp evaluate pregrasp --source synthetic   # Q1 / PN / Div table of the synthesised grasps
    multigrasp evaluate execution                     # lift success of the specialists (Syn-Pl / Com / Geo)
    multigrasp evaluate execution --source generated  # ... on the generator's pre-grasps (Gen-Pl / Com / Geo)
    multigrasp evaluate generalist                    # lift success of the distilled vision-based generalist
    multigrasp evaluate curriculum                    # Table II(c): adapted specialists, w/o Adpt, w/o Curr
    multigrasp generate --objects cube,cylinder --n 16  # pre-grasps from the trained generator
    multigrasp ui                               # MLflow UI on 127.0.0.1 for the work dir
    multigrasp prune --profile bench --keep mini  # delete stage outputs no named config uses (--yes to delete)
    multigrasp report                           # the work dir's results beside the paper's tables
    multigrasp bench kinematics --json out.json # FK + distance timings
    multigrasp bench synthesis --json out.json  # synthesis throughput on a fixed dual-object scene
    multigrasp bench sim --json out.json        # lift env steps/s vs bare PyBullet (overhead_ratio)
    multigrasp bench generation --json out.json # 256 pre-grasps: sampling + IK + refinement time

Every command that reads a config takes ``--profile``, ``--config FILE``, repeatable
``--set a.b=value``, ``--workdir``, ``--device`` and ``--runner``.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from components.errors import MultigraspError

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130
DEFAULT_UI_PORT = 5000
UI_HOST = "127.0.0.1"
#: the most MLflow server workers ``multigrasp ui`` starts by default (MLflow's own default)
UI_MAX_DEFAULT_WORKERS = 4


def port_is_free(host: str, port: int) -> bool:
    """Whether a server could listen on ``host:port`` now (``multigrasp ui`` checks before it starts MLflow, whose
    server otherwise logs 'Address already in use' and exits 0)."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        try:
            sock.bind((host, port))
        except OSError:
            return False
    return True


def _config_args(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("configuration")
    group.add_argument("--profile", default="smoke",
                       help="profile in configs/: smoke (minutes on a laptop, plumbing only), mini (~75 min: one "
                            "pair, real data), bench (the scaled-down full experiment on 2 CPU cores: hours per stage, "
                            "see README), paper (the paper's scale, GPU/cluster). Default: smoke")
    group.add_argument("--config", type=Path, metavar="FILE", help="YAML file merged over the profile")
    group.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                       help="override one config value, YAML-parsed (repeatable), e.g. --set run.seed=3 "
                            "--set objects.train=[cube,cylinder]")
    group.add_argument("--workdir", type=Path, help="work directory for artifacts, caches and the MLflow store "
                                                     "(default ./runs)")
    group.add_argument("--device", choices=["cpu", "cuda"], help="torch device for model code (default cpu)")
    group.add_argument("--runner", choices=["threads", "processes", "ray"],
                       help="Prefect task runner for fan-out (default threads); the evaluations' lift jobs go to "
                       "spawned processes, or to Ray tasks with ray")
    group.add_argument("--max-workers", type=int,
                       help="parallel workers of the task runner, and the evaluations' lift processes")
    group.add_argument("-v", "--verbose", action="store_true", help="log cache decisions, Prefect's messages and the INFO lines of MLflow and torchrl")


def _load(args: argparse.Namespace, needs_device: bool = True):
    """The config of the command's options; with ``needs_device``, first a one-line error where the device it names
    (``--device``, or ``run.device`` from the profile / file / ``--set``) cannot be used here, before any stage runs."""
    from components.device import require_device
    from flows.config import load_config
    from flows.runtime import apply_allocator

    cfg = load_config(args.profile, args.config, args.sets, workdir=args.workdir, device=args.device,
                      runner=args.runner, max_workers=args.max_workers)
    apply_allocator(cfg.run)
    if needs_device:
        require_device(cfg.run.device, "--device" if args.device else f"run.device of profile {cfg.profile!r} (or --config / --set)")
    return cfg


def _using(cfg, create: bool = False):
    """The work dir's lock, shared, for a command that reads or writes its units: a ``prune --yes`` waits for none of
    them and none of them starts while one deletes."""
    from tasks.artifacts import LOCKS_DIR, workdir_in_use

    workdir = cfg.run.workdir
    if create or workdir.is_dir():  # a work dir that cannot be made or written: one line, not an OSError from a lock
        locks = workdir / LOCKS_DIR
        try:
            locks.mkdir(parents=True, exist_ok=True)
            writable = os.access(locks, os.W_OK)
        except OSError as exc:
            raise MultigraspError(f"cannot use the work dir {workdir}: {exc.strerror or exc} at {exc.filename or locks}"
                                  " — pass --workdir a folder you can write") from None
        if not writable:
            raise MultigraspError(f"cannot write in the work dir {workdir} — pass --workdir a folder you can write, or "
                                  "fix its permissions")

    def waiting() -> None:
        print(f"a prune is deleting unused outputs of {cfg.run.workdir}; waiting for it", file=sys.stderr, flush=True)

    return workdir_in_use(cfg.run.workdir, on_wait=waiting, create=create)


class VersionAction(argparse.Action):
    """``--version``: :func:`tasks.tracking.version_line` (the same provenance every MLflow run is tagged with)."""

    def __init__(self, option_strings, dest, **kwargs):
        super().__init__(option_strings, dest, nargs=0, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        from tasks.tracking import version_line

        print(version_line())
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="multigrasp",
        description="MultiGrasp: dexterous multi-object grasping with one Shadow Hand. Every stage is a cached "
                    "Prefect task tracked in MLflow; re-running a command resumes where it stopped.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Start with `multigrasp run --profile smoke`, then `multigrasp ui`.")
    parser.add_argument("--version", action=VersionAction,
                        help="print the package version, its git commit, torch and Python, and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    run = sub.add_parser("run", help="run the pipeline (every stage, or up to --until); cached stages are reused",
                         description="Run the pipeline stages in order. Finished units are served from the cache, "
                                     "so re-running after a crash (even kill -9) recomputes only what had not "
                                     "finished. One MLflow parent run per invocation, one child run per stage.")
    _config_args(run)
    run.add_argument("--until", metavar="STAGE", help="stop after this stage (see `multigrasp stages`)")
    run.add_argument("--only", metavar="STAGE", action="append", help="run only this stage (repeatable); "
                                                                       "its upstream must be done")
    run.add_argument("--evaluate", action="store_true",
                     help="after the stages, run every `multigrasp evaluate` whose results are not current for this "
                          "config (Table I: pregrasp synthetic and generated, execution of both), then `report`")
    run.add_argument("--ablations", action="store_true",
                     help="with --evaluate: also the generator's and the execution's ablations (Table II; trains "
                          "the ablation specialists)")

    st = sub.add_parser("status", help="list each stage of a config as done / partial / stale / corrupt / missing",
                        description="Inspect the work dir without running anything: for every stage of the "
                                    "given config, whether its outputs exist and verify (done), some units exist "
                                    "(partial), only other configs' outputs exist (stale), files were altered "
                                    "(corrupt), nothing exists (missing), or its upstream is not done (blocked).")
    _config_args(st)
    st.add_argument("--json", action="store_true", help="print the same as one JSON object (stages, evaluations, the "
                                                        "command that computes what is not current), for scripts")

    sub.add_parser("stages", help="show the stage DAG and what each stage does",
                   description="List the pipeline's stages in execution order with their upstream stages.")

    cf = sub.add_parser("config", help="print the resolved config (profile <- --config <- --set) as YAML",
                        description="Print the config a command with the same options would run, every key with its "
                                    "value, as YAML that --config reads back (`multigrasp config --profile bench > "
                                    "my.yaml` starts a file of your own). Runs nothing and reads no work dir.")
    _config_args(cf)
    cf.add_argument("--key", metavar="KEY", help="only this part of the config, e.g. synthesis.optimizer or "
                                                 "specialists.ppo.lr")
    cf.add_argument("--describe", action="store_true", help="each field's documentation as a comment above it")

    upstream = (" Its upstream stages run first where they are not done for the same config (served from cache "
                "where they are); `multigrasp run --only STAGE` runs the stage alone.")
    sc = sub.add_parser("scenes", help="run the scenes stage (placements, settling, renders)",
                        description="Sample tabletop placements for every object combination of the profile, "
                                    "settle them in PyBullet, save them and render a few to PNG (MLflow).")
    _config_args(sc)

    sy = sub.add_parser("synthesize", help="run the synthesize stage (grasps per scene, Q1 / PN, renders)",
                        description="Synthesise multi-object pre-grasps for the scenes of the scenes stage (DFC "
                                    "energy, annealed MALA with contact switching, Adam refinement, filter), "
                                    "measure Q1 and PN of the accepted ones, write Parquet tables, statistics and "
                                    "render grids (MLflow)." + upstream)
    _config_args(sy)

    for name, stage, text in SINGLE_STAGE_COMMANDS[2:]:
        single = sub.add_parser(name, aliases=[stage] if stage != name else [], help=f"run the {stage} stage ({text})",
                                description=f"Run the {stage} stage: {text}." + upstream)
        _config_args(single)

    ge = sub.add_parser("generate", help="pre-grasps for any objects from the trained generator (+ IK, refinement, renders)",
                        description="Sample pre-grasps with the train-generator stage's model for a sampled scene of "
                                    "--objects (or the scene of --placement), convert them by IK, refine them, and "
                                    "write grasps.json, scene.json and a render grid to <workdir>/results/generated/.")
    ge.add_argument("--objects", type=lambda s: [x.strip() for x in s.split(",") if x.strip()], default=[],
                    help="comma-separated object names (library or user meshes), e.g. cube,cylinder")
    ge.add_argument("--n", type=int, default=16, help="grasps to generate (default 16)")
    ge.add_argument("--palm-direction", type=float, default=None, metavar="DEG",
                    help="palm direction about z in degrees (default: a random direction per grasp)")
    ge.add_argument("--placement", type=Path, default=None, metavar="FILE",
                    help="scene JSON ({'objects': [{'name', 'position', 'quat_xyzw'}]}) instead of a sampled scene")
    ge.add_argument("--seed", type=int, default=0, help="seed of the scene sampling and of the diffusion noise")
    ge.add_argument("--lift", action="store_true",
                    help="then lift the grasps the paper's protocol filter keeps in PyBullet with the matching "
                         "specialists (and w/o RL, the scripted squeeze; the distilled generalist where the "
                         "distill stage has run): lift.json, per-pose outcomes and GIFs beside the grasps; two "
                         "objects; needs the specialists stage")
    _config_args(ge)

    ev = sub.add_parser("evaluate", help="evaluation tables (pregrasp: Q1 / PN / Div per split; execution: lift success)",
                        description="Write an evaluation table to <workdir>/results/ (JSON + markdown) and log it "
                                    "to its own MLflow run. `pregrasp --source synthetic` measures the grasps of "
                                    "the synthesize stage per split (Syn-Pl, Syn-Com, Syn-Geo: dual-object, as the paper; "
                                    "Syn-train-pairs; Syn-Pl-singles, Syn-Geo-singles); `pregrasp --source generated` scores the "
                                    "trained generator's pre-grasps on the evaluation scenes (Gen-Pl, Gen-Com, Gen-Geo); "
                                    "`execution` lifts Syn-Pl / Syn-Com / Syn-Geo pre-grasps with the matching "
                                    "specialists (5 seeded trials per pose by default); `execution --source "
                                    "generated` lifts the generator's (Gen-Pl / Gen-Com / Gen-Geo).")
    ev.add_argument("target", choices=["pregrasp", "execution", "generalist", "curriculum"],
                    help="what to evaluate: pregrasp (Q1 / PN / Div), execution (lift success of the specialists), "
                         "generalist (lift success of the distilled vision-based generalist on the same poses) or "
                         "curriculum (Table II(c): the adapted specialists against w/o Adpt and w/o Curr on Gen-Pl)")
    ev.add_argument("--source", choices=["synthetic", "generated"], default=None,
                    help="where the pre-grasps come from: synthetic = the synthesize stage, generated = the "
                         "train-generator stage's model on the evaluation scenes (refined, kept by the paper's "
                         "protocol filter). Required for pregrasp; execution: default synthetic (Syn rows), "
                         "generated lifts the Gen rows' pre-grasps -> results/execution_generated.json")
    ev.add_argument("--ablations", action="store_true",
                    help="execution: also train and evaluate the specialists of the ablations (w/o Goal, w/o Spe-*); "
                         "pregrasp --source generated: the generator's (Joint Angles, w/o Obj Embd, w/o Refinement) "
                         "-> results/ablation_generator.json")
    _config_args(ev)

    rp = sub.add_parser("report", help="the work dir's evaluation results beside the paper's Tables I and II "
                                       "-> results/report.md",
                        description="Collect what `multigrasp evaluate` wrote under <workdir>/results/ into one "
                                    "markdown file, every figure beside the paper's (Table I: Syn / Gen x Pl / Com / "
                                    "Geo; Table II: ablations), with the profile and time of each evaluation and the "
                                    "command for any that has not run. Nothing is recomputed.")
    rp.add_argument("--workdir", type=Path, default=Path("runs"), help="work directory (default ./runs)")

    cp = sub.add_parser("compare", help="several work dirs' evaluation results side by side, with the paper's",
                        description="Read the evaluation results of each work dir (what `multigrasp report` reads) and "
                                    "print one markdown table: a row per figure any of them has, a column per work "
                                    "dir, the paper's last. For variants run in separate work dirs (each has its own "
                                    "MLflow store; variants in one work dir compare in its MLflow UI). Nothing is "
                                    "recomputed.")
    cp.add_argument("workdirs", type=Path, nargs="+", metavar="WORKDIR", help="work directories to compare")
    cp.add_argument("--label", dest="labels", action="append", default=[], metavar="NAME",
                    help="column name of each work dir, in order (default: the folder names); repeat per work dir")
    cp.add_argument("--out", type=Path, metavar="FILE", help="also write the table to this markdown file")

    pr = sub.add_parser("prune", help="delete the stage outputs that no kept config uses (dry run unless --yes)",
                        description="List, then with --yes delete, the unit folders under <workdir>/stages/ that the "
                                    "named configs do not use now: outputs of changed settings, of other profiles, "
                                    "and of older code (an upgrade changes every key). Every unit the configs plan "
                                    "now is kept -- done, running, interrupted (a training's checkpoint) -- with "
                                    "those of their ablation variants. Name every config you still want to resume "
                                    "or evaluate: --profile (with --config / --set) and --keep for each other one.")
    _config_args(pr)
    pr.set_defaults(profile=None)
    pr.add_argument("--keep", action="append", default=[], metavar="PROFILE[:FILE]",
                    help="another config whose outputs to keep (repeatable): a profile, or a profile and a YAML file "
                         "merged over it, e.g. --keep mini --keep bench:my.yaml")
    pr.add_argument("--yes", action="store_true", help="delete (without it, only print what would be deleted)")

    ui = sub.add_parser("ui", help="start the MLflow UI on 127.0.0.1 for the work dir",
                        description="Serve the MLflow UI for the work dir's store (or MLFLOW_TRACKING_URI) on "
                                    "127.0.0.1. Stop it with Ctrl-C.")
    ui.add_argument("--workdir", type=Path, default=Path("runs"), help="work directory (default ./runs)")
    ui.add_argument("--port", type=int, default=DEFAULT_UI_PORT, help=f"port (default {DEFAULT_UI_PORT})")
    ui.add_argument("--workers", type=int, default=None,
                    help=f"MLflow server worker processes (default: the machine's cores, at most "
                         f"{UI_MAX_DEFAULT_WORKERS}; each extra one slows the start on few cores)")

    bench = sub.add_parser("bench", help="speed benchmarks that write JSON (see benchmarks/)",
                           description="Run a benchmark and write its JSON (medians of several runs).")
    bench.add_argument("name", choices=["kinematics", "synthesis", "sim", "generation"], help="which benchmark")
    bench.add_argument("--json", type=Path, required=True, metavar="OUT", help="where to write the JSON result")
    bench.add_argument("--repeats", type=int, default=7, help="timed runs (median reported); default 7")
    bench.add_argument("--threads", type=int, default=0, help="torch threads (0 = torch default)")
    bench.add_argument("--device", choices=["cpu", "cuda"], default="cpu", help="torch device")
    bench.add_argument("--steps-scale", type=float, default=1.0,
                       help="synthesis: multiply the bench profile's approach / MALA / refinement steps (e.g. 0.01 for a "
                            "quick check); default 1")
    bench.add_argument("--profile", default=None,
                       help="generation: the profile whose generator settings are timed (default bench: DDIM 25 + "
                            "50 refinement steps; paper: the paper's 100 DDPM + 200 refinement steps)")
    bench.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                       help="generation: override a value of the generator stage (repeatable), e.g. --set "
                            "sampler.steps=10 --set refine.steps=30")
    return parser


# --------------------------------------------------------------------------- commands


#: single-stage commands: (command, stage, what it does).  DESIGN §1 names the PPO stage ``train-lifting``.
SINGLE_STAGE_COMMANDS = [
    ("scenes", "scenes", "placements, settling, renders"),
    ("synthesize", "synthesize", "grasps per scene, Q1 / PN, renders"),
    ("train-generator", "train-generator", "the diffusion pre-grasp generator; resumes from its last checkpoint"),
    ("pointnet", "pointnet", "pre-training of the frozen PointNet encoder of the lift policies"),
    ("train-lifting", "specialists", "bins of the training pre-grasps and one TorchRL PPO lift specialist per bin; "
                                     "each resumes from its last checkpoint"),
    ("reach", "reach", "planned reaches to the specialists' pre-grasps, run in PyBullet"),
    ("curriculum", "curriculum", "each specialist adapted to reached and generated pre-grasps in three phases; "
                                 "resumes from its last checkpoint"),
    ("distill", "distill", "DAgger of the specialists into one vision-based generalist; resumes from its last "
                           "iteration"),
]


def _single_stage(command: str, stage: str):
    """The handler of a single-stage command: the stage and its upstream (:func:`flows.pipeline.with_upstream`).
    The pipeline (torch, Prefect, every stage's code: ~12 s to import on a slow day) is imported when the handler
    runs, not when it is made: ``main`` makes one for every stage command, whichever command it runs."""

    def handler(args: argparse.Namespace) -> int:
        from flows.pipeline import with_upstream

        return _cmd_run(args, command=command, only=with_upstream(stage))

    return handler


def _cmd_run(args: argparse.Namespace, command: str = "run", only: list[str] | None = None) -> int:
    from flows.pipeline import run_pipeline, select_stages
    from tasks.tracking import ui_command

    cfg = _load(args)
    evaluate = getattr(args, "evaluate", False)
    if getattr(args, "ablations", False) and not evaluate:
        raise MultigraspError("--ablations belongs to --evaluate — add --evaluate, or use `multigrasp evaluate ... "
                              "--ablations`")
    if evaluate and (only or args.only or getattr(args, "until", None)):
        raise MultigraspError("--evaluate needs every stage — drop --until / --only, or run `multigrasp evaluate` "
                              "for what those stages feed")
    modules = select_stages(only=only if only is not None else args.only, until=getattr(args, "until", None))
    report, evaluated, evaluate_s = None, 0, 0.0
    with _using(cfg, create=True):
        ctx = run_pipeline(cfg, modules, command=command)
        if evaluate:
            from flows.evaluations import run_evaluations

            started = time.perf_counter()
            report, evaluated = run_evaluations(cfg, args.ablations, ctx.console.print,
                                                parent_run_id=ctx.parent_run_id)
            evaluate_s = time.perf_counter() - started
    console = ctx.console
    executed = sum(r.executed for r in ctx.results.values())
    cached = sum(r.cached for r in ctx.results.values())
    all_cached = executed == 0
    total = f"{ctx.wall_s + evaluate_s:.1f}s wall time ({ctx.wall_s:.1f}s stages, {evaluate_s:.1f}s evaluations)" \
        if evaluate else f"{ctx.wall_s:.1f}s wall time"
    console.print(f"\n[bold]done[/] in {total} — {executed} unit(s) computed, {cached} served "
                  f"from cache{' (every stage served from cache)' if all_cached else ''}")
    console.print(f"results:   {cfg.run.workdir}   (stages/, results/)")
    if evaluate:
        where = report.path if report is not None else cfg.run.workdir / "results"
        console.print(f"tables:    {where} ({evaluated} evaluation(s) computed; the paper's figures beside "
                      "each cell; JSON and markdown per evaluation beside it)")
    console.print(f"MLflow:    parent run {ctx.parent_run_id} in {ctx.tracking_uri}")
    link = run_url(ctx.tracking_uri, ctx.tracker.experiment_id, ctx.parent_run_id)
    if ctx.tracking_uri.startswith(("http://", "https://")):
        console.print(f"open UI:   {link}   (this run)")
    else:
        console.print(f"open UI:   {ui_command(cfg.run.workdir)}   → {link}   (this run)")
    return 0


def run_url(tracking_uri: str, experiment_id: str, run_id: str, port: int = DEFAULT_UI_PORT) -> str:
    """The MLflow UI's page of a run: on the tracking server where ``MLFLOW_TRACKING_URI`` names one, else on the
    server `multigrasp ui` starts (127.0.0.1:``port``)."""
    base = tracking_uri.rstrip("/") if tracking_uri.startswith(("http://", "https://")) else f"http://{UI_HOST}:{port}"
    return f"{base}/#/experiments/{experiment_id}/runs/{run_id}"


def _cmd_status(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from flows.pipeline import status
    from flows.report import TABLE_ONE_FILES, evaluation_status

    cfg = _load(args, needs_device=False)  # status reads files only: a cluster's work dir, checked on a laptop
    rows = status(cfg)
    has_results = (cfg.run.workdir / "results").is_dir()
    evaluations = evaluation_status(cfg, finals={r.name: r.folder for r in rows}) if has_results else []  # verified once
    pending = any(row.state != "current" for row in evaluations if row.name in TABLE_ONE_FILES)
    if args.json:
        return _print_status_json(args, cfg, rows, evaluations, pending or not has_results)
    table = Table(title=f"multigrasp status — profile {cfg.profile}, workdir {cfg.run.workdir}")
    for col in ("stage", "state", "units"):
        table.add_column(col, no_wrap=True)
    # the output folder relative to the work dir (in the title), folded rather than cut: on an 80-column terminal
    # rich cut the absolute path to "/work/…/st…", the one thing a user reads the column for
    table.add_column("output (in workdir)", overflow="fold")
    table.add_column("note")
    colors = {"done": "green", "partial": "yellow", "stale": "magenta", "corrupt": "red", "missing": "white",
              "blocked": "dim"}
    for row in rows:
        table.add_row(row.name, f"[{colors[row.state]}]{row.state}[/]", f"{row.done_units}/{row.known_units}",
                      _within(row.folder, cfg.run.workdir) if row.folder else "-", row.detail)
    console = Console()
    console.print(table)
    if has_results:
        results = Table(title=f"evaluations in {cfg.run.workdir / 'results'}")
        for col in ("results file", "state", "note"):
            results.add_column(col)
        shades = {"current": "green", "stale": "magenta", "unknown": "yellow", "missing": "white"}
        for row in evaluations:
            results.add_row(row.name, f"[{shades[row.state]}]{row.state}[/]", row.detail)
        console.print(results)
        if pending:
            from rich.markup import escape

            # escaped for rich, which took `[mug]` of `--set objects.ood=[mug]` for a tag
            console.print(f"`{escape(_evaluate_command(args, cfg))}` computes the Table I evaluations that are not "
                          "current, then the report")
    return 0


def _evaluate_command(args: argparse.Namespace, cfg) -> str:
    """``multigrasp run --evaluate`` with this command's config options, to paste into a shell: each value quoted
    where it needs it (``--set objects.user=[{name: mug, ...}]`` holds spaces)."""
    import shlex

    options = ["--profile", cfg.profile] + (["--config", str(args.config)] if args.config else [])
    options += [word for item in args.sets for word in ("--set", item)] + ["--workdir", str(cfg.run.workdir)]
    return shlex.join(["multigrasp", "run", "--evaluate", *options])


def _print_status_json(args: argparse.Namespace, cfg, rows: list, evaluations: list, pending: bool) -> int:
    """``status --json``: what the tables say, as one JSON object on stdout (``stages``: name, state, done_units,
    known_units, folder, detail; ``evaluations``: name, state, detail; ``evaluate_command``: the command that computes
    the Table I evaluations that are not current, or null)."""
    import dataclasses
    import json

    print(json.dumps({
        "profile": cfg.profile, "workdir": str(cfg.run.workdir),
        "stages": [{**dataclasses.asdict(row), "folder": str(row.folder) if row.folder else None} for row in rows],
        "evaluations": [{"name": row.name, "state": row.state, "detail": row.detail} for row in evaluations],
        "evaluate_command": _evaluate_command(args, cfg) if pending else None}, indent=2))
    return 0


def _within(path: str | Path, root: Path) -> str:
    """``path`` relative to ``root`` where it lies under it, else as it is."""
    try:
        return str(Path(path).relative_to(root))
    except ValueError:
        return str(path)


def _cmd_report(args: argparse.Namespace) -> int:
    from flows.report import write_report

    report = write_report(args.workdir)
    print(report.markdown)
    print(f"written: {report.path}  {report.csv_path}  (MLflow run {report.run_id})")
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:
    from flows.report import compare_markdown
    from tasks.artifacts import atomic_write_text

    markdown = compare_markdown(args.workdirs, args.labels or None)
    print(markdown, end="")
    if args.out:
        print(f"written: {atomic_write_text(args.out, markdown)}")
    return 0


def _cmd_prune(args: argparse.Namespace) -> int:
    from flows.config import load_config
    from flows.prune import human_bytes, plan_lines, prune

    if args.profile is None:
        raise MultigraspError("prune keeps only what the configs you name use — pass --profile (with the --config / "
                              "--set of your runs) and --keep PROFILE[:FILE] for every other config in this work dir")
    cfg = _load(args, needs_device=False)
    configs, labels = [cfg], [_label(args.profile, args.config, args.sets)]
    for item in args.keep:
        profile, _, file = item.partition(":")
        configs.append(load_config(profile, Path(file) if file else None, [], workdir=cfg.run.workdir))
        labels.append(_label(profile, Path(file) if file else None, []))
    plan, freed = prune(configs, labels, delete=args.yes)
    for line in plan_lines(plan):
        print(line)
    if plan.candidates and not args.yes:
        print(f"would delete {len(plan.candidates)} folder(s), {human_bytes(plan.bytes)} — run again with --yes to "
              "delete them")
    elif args.yes:
        print(f"deleted {len(plan.candidates)} folder(s); {human_bytes(freed)} freed")
    return 0


def _label(profile: str, config: Path | None, sets: list[str]) -> str:
    return " ".join([f"profile {profile}"] + ([f"+ {config}"] if config else []) + [f"--set {s}" for s in sets])


def _cmd_config(args: argparse.Namespace) -> int:
    from flows.config import config_yaml

    cfg = _load(args, needs_device=False)  # printing a paper-profile config needs no GPU
    sys.stdout.write(config_yaml(cfg, args.key, args.describe))
    return 0


def _cmd_stages(_: argparse.Namespace) -> int:
    from flows.pipeline import STAGES

    for i, module in enumerate(STAGES, 1):
        after = f"  (after {', '.join(module.UPSTREAM)})" if module.UPSTREAM else ""
        print(f"{i}. {module.STAGE:<16} {module.DESCRIPTION}{after}")
    print(f"   {'(evaluations)':<16} with `run --evaluate`: every `multigrasp evaluate` not current for the config "
          "(Table I; + --ablations: Table II), then `multigrasp report`  (after every stage)")
    return 0


#: a ``PYTHONWARNINGS`` entry for the MLflow server of ``multigrasp ui`` (see :func:`_cmd_ui`)
UI_QUIET_WARNING = "ignore:starlette.middleware.wsgi is deprecated"


def ui_workers(asked: int | None) -> int:
    """The MLflow server's worker processes for ``multigrasp ui``: ``asked``, else one per core up to
    :data:`UI_MAX_DEFAULT_WORKERS`.  Each worker imports MLflow as it starts, so on 2 cores MLflow's 4 took 29 s to
    answer against 24 s for 2, and served 32 concurrent run searches no faster (docs/benchmarks.md)."""
    if asked is None:
        return max(1, min(UI_MAX_DEFAULT_WORKERS, os.cpu_count() or 1))
    if asked < 1:
        raise MultigraspError(f"--workers must be at least 1 (got {asked}) — e.g. --workers 2")
    return asked


def _cmd_ui(args: argparse.Namespace) -> int:
    from tasks.tracking import artifact_root, default_tracking_uri, relocate_embedded_store

    workdir = args.workdir.resolve()
    if not os.environ.get("MLFLOW_TRACKING_URI") and not (workdir / "mlflow.db").exists():
        raise MultigraspError(f"no MLflow store in {workdir} — run `multigrasp run` first or pass --workdir")
    if not 0 < args.port < 65536:
        raise MultigraspError(f"--port must be between 1 and 65535 (got {args.port})")
    workers = ui_workers(args.workers)
    if not port_is_free(UI_HOST, args.port):
        raise MultigraspError(f"port {args.port} on {UI_HOST} is in use (another `multigrasp ui` or MLflow server?) — "
                              f"open that one, stop it, or pass --port {args.port + 1}")
    old = relocate_embedded_store(workdir)  # a copied work dir shows its own PNGs, not the old place's
    if old:
        print(f"artifact locations of {workdir / 'mlflow.db'} moved from {old} to {artifact_root(workdir)}", flush=True)
    cmd = [sys.executable, "-m", "mlflow", "server", "--backend-store-uri", default_tracking_uri(workdir),
           "--default-artifact-root", artifact_root(workdir), "--host", UI_HOST, "--port", str(args.port),
           "--workers", str(workers)]
    print(f"MLflow UI on http://{UI_HOST}:{args.port} (Ctrl-C to stop)", flush=True)
    # MLflow's server imports a Starlette module that warns of its own deprecation, once per server process (three
    # copies of two lines on every start): not the user's to act on
    quiet = ",".join(filter(None, [os.environ.get("PYTHONWARNINGS"), UI_QUIET_WARNING]))
    try:
        return subprocess.call(cmd, env={**os.environ, "PYTHONWARNINGS": quiet})
    except KeyboardInterrupt:
        return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    import json

    from components.device import require_device

    if (args.sets or args.profile) and args.name != "generation":
        raise MultigraspError(f"--set / --profile apply to `bench generation` only (got them with `bench {args.name}`) "
                              "— drop them")

    require_device(args.device)
    from flows.config import RunConfig
    from flows.runtime import apply_allocator

    allocator = apply_allocator(RunConfig())  # the allocator settings every command runs with (RunConfig's defaults)
    if args.name == "synthesis":
        from benchmarks.synthesis import run_synthesis_benchmark

        if args.steps_scale <= 0:
            raise MultigraspError(f"--steps-scale must be > 0 (got {args.steps_scale}) — e.g. 0.01 for a quick check")
        result = run_synthesis_benchmark(repeats=args.repeats, threads=args.threads, device=args.device,
                                         steps_scale=args.steps_scale)
    elif args.name == "generation":
        from benchmarks.generation import run_generation_benchmark

        result = run_generation_benchmark(repeats=args.repeats, threads=args.threads, device=args.device,
                                          sets=tuple(args.sets), profile=args.profile or "bench")
    elif args.name == "sim":
        from benchmarks.sim import run_sim_benchmark

        result = run_sim_benchmark(repeats=args.repeats)
    else:
        from benchmarks.kinematics import run_kinematics_benchmark

        result = run_kinematics_benchmark(repeats=args.repeats, threads=args.threads, device=args.device)
    result["allocator"] = allocator  # the glibc settings applied (bytes by variable; {} = the C library's defaults)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    return 0


def _single_report_evaluation(args: argparse.Namespace):
    """The evaluation function of the ``evaluate`` targets that write one results file (``execution --source
    generated``, ``curriculum``, ``generalist``), after a one-line error for an option it does not take; None for the
    others."""
    if args.target == "execution" and args.source == "generated":
        if args.ablations:
            raise MultigraspError("--ablations applies to `evaluate execution` of synthesised pre-grasps — drop "
                                  "--source generated, or drop --ablations")
        from flows.evaluate_generated_execution import evaluate_generated_execution

        return evaluate_generated_execution
    if args.target not in ("curriculum", "generalist"):
        return None
    if args.ablations or args.source is not None:
        what = ("lifts generated pre-grasps and is itself an ablation (Table II(c))" if args.target == "curriculum"
                else "lifts both the synthesised and the generated pre-grasps (Syn and Gen rows) and has no ablations")
        raise MultigraspError(f"evaluate {args.target} {what} — drop --source / --ablations")
    if args.target == "curriculum":
        from flows.evaluate_curriculum import evaluate_curriculum

        return evaluate_curriculum
    from flows.evaluate_generalist import evaluate_generalist

    return evaluate_generalist


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from flows.evaluate import evaluate_pregrasp

    cfg = _load(args)
    single = _single_report_evaluation(args)
    if single is not None:
        with _using(cfg):
            report = single(cfg)
        print(report.markdown)
        print(f"written: {report.json_path}")
        return 0
    if args.target == "execution":
        from flows.evaluate_execution import evaluate_execution

        with _using(cfg):
            report = evaluate_execution(cfg, ablations=args.ablations)
        print(report.markdown)
        print(f"written: {report.json_path}  {report.ablation_path}")
        print(f"per-pose outcomes: {report.json_path.parent / 'execution'}/<setting>/outcomes.json — compare two runs "
              "pose by pose with python -m benchmarks.paired_execution A B")
        return 0
    if args.source is None:
        raise MultigraspError("evaluate pregrasp needs --source synthetic (the synthesize stage's grasps) or --source "
                              "generated (the trained generator's) — e.g. multigrasp evaluate pregrasp --source synthetic")
    with _using(cfg):
        report = evaluate_pregrasp(cfg, args.source, ablations=args.ablations)
    print(report.markdown)
    print(f"written: {report.json_path}  {report.markdown_path}")
    return 0


def _cmd_generate(args: argparse.Namespace) -> int:
    from flows.generate import generate
    from flows.runtime import make_console

    cfg = _load(args)
    with _using(cfg):  # progress lines carry rich markup: the stderr console of the other commands renders it
        report = generate(cfg, args.objects, args.n, args.palm_direction, args.placement, args.seed, lift=args.lift,
                          say=make_console().print)
    print(f"{report.n} grasp(s) in {report.folder}  (sampling + IK {report.seconds['sample_and_ik_s']} s, refinement "
          f"{report.seconds['refine_s']} s; mean penetration {report.depth_before_mm:.2f} -> {report.depth_after_mm:.2f} mm; "
          + (f"{report.kept} kept by the protocol filter)" if cfg.generator.eval_filter.enabled else
             "the protocol filter off: every grasp kept)"))
    lifted = report.lift
    if lifted is not None:
        if not lifted.kept:
            print(f"lift: none of the {report.n} grasps passed the protocol filter (generator.eval_filter), so none "
                  "was lifted — ask for more with --n, or try another --seed")
        else:
            def pct(rate):
                return "–" if rate is None else f"{100 * rate:.1f} %"

            print(f"lift: {lifted.poses} pose(s) x {lifted.trials} trial(s) with {', '.join(lifted.specialists) or '-'}: "
                  f"specialist {pct(lifted.succ)}, w/o RL {pct(lifted.without_rl)}, squeeze {pct(lifted.squeeze)}"
                  + ("" if lifted.generalist is None else f", generalist {pct(lifted.generalist)}")
                  + f"; {lifted.path} ({len(lifted.gifs)} GIF(s))")
    print(f"MLflow run {report.run_id} (generate:{report.folder.name.rsplit('-', 1)[0]})")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "verbose", False):  # before Prefect is imported: it reads its level once
        os.environ["PREFECT_LOGGING_LEVEL"] = "INFO"
    else:  # before MLflow is imported: it sets its loggers' level from this once (its default, INFO, printed
        # "Creating initial MLflow database tables..." lines into every first run of a work dir)
        os.environ.setdefault("MLFLOW_LOGGING_LEVEL", "WARNING")
        # torchrl's own handler prints INFO lines ("Initialized LazyTensorStorage ...") into every PPO training; its
        # level is read from this at import, also in worker processes
        os.environ.setdefault("RL_LOGGING_LEVEL", "WARNING")
    from flows.library_logs import configure_console_logging, quiet_handled_warnings

    configure_console_logging(getattr(args, "verbose", False))
    quiet_handled_warnings()
    if not getattr(args, "verbose", False):
        logging.getLogger("mlflow").setLevel(logging.WARNING)
        logging.getLogger("torchrl").setLevel(logging.WARNING)  # where torchrl was imported before main()
    handlers = {"run": _cmd_run, "status": _cmd_status, "stages": _cmd_stages, "config": _cmd_config, "ui": _cmd_ui,
                "prune": _cmd_prune, "compare": _cmd_compare,
                "report": _cmd_report,
                "bench": _cmd_bench, "evaluate": _cmd_evaluate, "generate": _cmd_generate,
                **{name: _single_stage(name, stage) for name, stage, _ in SINGLE_STAGE_COMMANDS},
                **{stage: _single_stage(name, stage) for name, stage, _ in SINGLE_STAGE_COMMANDS}}
    stopper = Interrupts()
    previous = stopper.install()
    try:
        return handlers[args.command](args)
    except MultigraspError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print(INTERRUPTED_MESSAGE, file=sys.stderr)
        return EXIT_INTERRUPTED
    except RuntimeError as exc:
        if "ephemeral Prefect API server" not in str(exc):
            raise
        print(f"error: {SERVER_TIMEOUT_MESSAGE}", file=sys.stderr)
        return EXIT_USER_ERROR
    finally:
        if not stopper.count:  # after an interrupt, keep the handler: a second signal during shutdown stops at once
            for signum, handler in previous.items():
                signal.signal(signum, handler)


SERVER_TIMEOUT_MESSAGE = ("Prefect's temporary API server did not start in time (is the machine busy?); nothing was "
                          "lost — run the same command again, or allow it longer with "
                          "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS=300")
INTERRUPTED_MESSAGE = "interrupted — finished units are kept; run the same command again to resume"


class Interrupts:
    """Ctrl-C (SIGINT) and ``kill PID`` (SIGTERM: also what a cluster scheduler sends at pre-emption or its time
    limit) stop a command in two steps.

    1. The first signal raises KeyboardInterrupt in the main thread: the stack unwinds through the context
       managers, so the helper processes this invocation started (Prefect's temporary API server, collector
       workers) are stopped, and the 'finished units are kept' line is printed.  A unit running in a worker
       *thread* (a shard, a generator training) cannot be interrupted from outside and would run to its end, so
       the handler says so and how to stop at once.
    2. A second signal stops now: it terminates this process's child processes and exits with
       EXIT_INTERRUPTED.  Nothing finished is lost -- units are written atomically with their manifest last, and
       trainings resume from their last checkpoint.

    ``exit`` and ``children`` are injectable for tests."""

    def __init__(self, exit=os._exit, children=None, stream=None):
        self.count = 0
        self._exit, self._stream = exit, stream
        self._children = children or _child_pids

    def install(self) -> dict:
        """Install the handler for SIGINT and SIGTERM; returns the previous handlers (empty outside the main thread,
        where Python allows no handler)."""
        if threading.current_thread() is not threading.main_thread():
            return {}
        return {signum: signal.signal(signum, self.handle) for signum in (signal.SIGINT, signal.SIGTERM)}

    def handle(self, signum, frame) -> None:
        self.count += 1
        stream = self._stream or sys.stderr
        if self.count == 1:
            print("stopping — a unit running in a worker thread (a shard, a training) finishes first; press Ctrl-C "
                  "again (or send SIGTERM again) to stop at once", file=stream, flush=True)
            raise KeyboardInterrupt
        for pid in self._children():
            try:
                os.kill(pid, signal.SIGTERM)
            except OSError:
                pass
        print(INTERRUPTED_MESSAGE, file=stream, flush=True)
        self._exit(EXIT_INTERRUPTED)


def _child_pids(parent: int | None = None) -> list[int]:
    """The child processes of ``parent`` (default: this process) (Linux /proc; elsewhere none are known)."""
    me, out = os.getpid() if parent is None else parent, []
    proc = Path("/proc")
    if not proc.is_dir():
        return out
    for stat in proc.glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if len(fields) > 1 and fields[1] == str(me):
            out.append(int(stat.parent.name))
    return out


if __name__ == "__main__":
    sys.exit(main())
