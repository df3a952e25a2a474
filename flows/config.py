"""The one config tree, its profiles and its overrides.

Every component owns its section (``HandConfig`` lives in ``components/hand``,
``ObjectsConfig`` in ``components/objects`` …); this module composes them into
:class:`PipelineConfig` and loads it::

    defaults  ←  configs/<profile>.yaml  ←  --config FILE  ←  --set a.b=value (repeatable)

A profile or ``--config`` file may start with ``include: [FILE, ...]`` (paths relative to that file): the included
files are merged first, in order, and the file's own keys on top of them.  The mesh paths a file names
(``objects.user`` meshes, ``objects.library_file``) are relative to that file too; those given to ``--set`` are
relative to the working directory.  Both are made absolute on load, so worker processes see the same files.  The bench and paper profiles share
their multi-object scene and synthesis setting this way (``configs/shared/multi_object.yaml``).

``--set`` values are parsed as YAML (``--set objects.train=[cube,cylinder]``,
``--set run.seed=3``).  An unknown key or a bad value raises :class:`MultigraspError`
with one line naming the key and what is allowed.
"""

from __future__ import annotations

import difflib
import functools
import logging
import re
import typing
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import Field, ValidationError, field_validator

from components.config_base import Section
from components.errors import MultigraspError
from components.execution.lift_config import LiftEnvConfig
from components.hand.config import HandConfig
from components.learning.curriculum import CurriculumConfig
from components.objects.config import ObjectsConfig
from tasks.distill import DistillStageConfig
from tasks.generator import GeneratorStageConfig
from tasks.pointnet import PointNetStageConfig
from tasks.reach import ReachStageConfig
from tasks.scenes import ScenesStageConfig
from tasks.specialists import SpecialistsStageConfig
from tasks.synthesize import SynthesisStageConfig
from tasks.tracking import DEFAULT_EXPERIMENT

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"


class RunConfig(Section):
    """How and where an invocation runs (not part of any cache key except ``seed``)."""

    workdir: Path = Field(Path("runs"), description="Work directory: stage artifacts, caches, results, MLflow store.")
    device: Literal["cpu", "cuda"] = Field("cpu", description="Torch device for model code.")
    runner: Literal["threads", "processes", "ray"] = Field(
        "threads", description="Prefect task runner used for fan-out (shards, specialists, evaluation).")
    max_workers: int = Field(2, ge=1, le=512, description="Parallel workers of the task runner, and the processes "
                             "that lift an evaluation's poses (`evaluate execution`; at most the machine's cores).")
    torch_threads: int = Field(0, ge=0, le=512, description="torch.set_num_threads for the run (0 = torch default); 1 when workers share few cores.")
    seed: int = Field(0, ge=0, description="Base random seed; every unit derives its own seed from it.")
    malloc_mmap_threshold_mb: int = Field(
        32, ge=0, le=32,
        description="glibc malloc: blocks at least this large (MiB) get their own mmap; smaller ones come from the heap "
        "(mallopt M_MMAP_THRESHOLD for the process, MALLOC_MMAP_THRESHOLD_ for the worker processes it starts; "
        "flows.runtime.apply_allocator).  With glibc's adaptive default, torch's many 1-30 MB temporaries are handed "
        "back to the kernel and faulted in again page by page: ~500,000 page faults per 256-grasp sampling, a quarter "
        "of its time on the development machine (docs/benchmarks.md 'Page faults').  0 = glibc's adaptive default; "
        "32 is glibc's largest.  Ignored where the C library is not glibc, or where the environment already sets "
        "MALLOC_MMAP_THRESHOLD_ to another value.")
    malloc_trim_threshold_mb: int = Field(
        1024, ge=0, le=2047,
        description="glibc malloc: free memory at the top of the heap is given back to the kernel only beyond this "
        "(MiB; mallopt M_TRIM_THRESHOLD / MALLOC_TRIM_THRESHOLD_), so freed tensors' pages are reused instead of "
        "faulted in again.  The peak resident memory is unchanged (measured: 0.84 GB either way for the sampling); "
        "memory freed after a peak stays with the process.  0 = glibc's adaptive default; as the other, a "
        "MALLOC_TRIM_THRESHOLD_ of another value in the environment wins.")
    ray_address: str | None = Field(None, description="Ray cluster address for runner=ray (None = start a local Ray).")


class TrackingConfig(Section):
    """MLflow tracking."""

    experiment: str = Field(DEFAULT_EXPERIMENT, min_length=1, description="MLflow experiment name.")
    renders: bool = Field(True, description="Log PNG/GIF renders as MLflow artifacts.")
    generator_sample_scenes: int = Field(
        2, ge=0, le=16,
        description="After a training of the generator, this many of its training scenes (the most objects first) "
        "get generator.eval_grasps_per_scene samples (IK and refinement included), scored and rendered beside the "
        "dataset's grasps of the same scene, in the train-generator run (with `renders`); 0 = none.  No stage "
        "output depends on it.")


class PipelineConfig(Section):
    """The whole pipeline: one section per component/stage."""

    profile: str = Field("custom", description="Name of the profile this config came from.")
    run: RunConfig = Field(default_factory=RunConfig, description="Execution settings.")
    tracking: TrackingConfig = Field(default_factory=TrackingConfig, description="MLflow settings.")
    hand: HandConfig = Field(default_factory=HandConfig, description="Shadow Hand model.")
    objects: ObjectsConfig = Field(default_factory=ObjectsConfig, description="Object library and user meshes.")
    scenes: ScenesStageConfig = Field(default_factory=ScenesStageConfig, description="Tabletop scene stage.")
    synthesis: SynthesisStageConfig = Field(default_factory=SynthesisStageConfig,
                                            description="Grasp synthesis stage (optimiser, metrics, scenes, renders).")
    lift: LiftEnvConfig = Field(default_factory=LiftEnvConfig,
                                description="PyBullet lift environment of the execution policies (physics, actions, reward).")
    generator: GeneratorStageConfig = Field(default_factory=GeneratorStageConfig,
                                            description="Diffusion pre-grasp generator, its IK and refinement.")
    pointnet: PointNetStageConfig = Field(default_factory=PointNetStageConfig,
                                          description="Pre-training of the point-cloud encoder (pointnet stage).")
    specialists: SpecialistsStageConfig = Field(default_factory=SpecialistsStageConfig,
                                                description="Binning of the pre-grasps and PPO of each specialist.")
    reach: ReachStageConfig = Field(default_factory=ReachStageConfig,
                                    description="Planned reaches to the specialists' pre-grasps, run in PyBullet (reach stage).")
    curriculum: CurriculumConfig = Field(default_factory=CurriculumConfig,
                                         description="Adaptation of the specialists to imprecise pre-grasps (curriculum stage).")
    distill: DistillStageConfig = Field(default_factory=DistillStageConfig,
                                        description="DAgger of the specialists into one vision-based generalist (distill stage).")

    @field_validator("run")
    @classmethod
    def _absolute_workdir(cls, run: RunConfig) -> RunConfig:
        return run.model_copy(update={"workdir": Path(run.workdir).expanduser().resolve()})


# --------------------------------------------------------------------------- loading


def available_profiles() -> list[str]:
    return sorted(p.stem for p in CONFIG_DIR.glob("*.yaml"))


def _read_yaml(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise MultigraspError(f"config file not found: {path} — check the path")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark else ""
        raise MultigraspError(f"config file {path} is not valid YAML{where} — fix its syntax") from None
    if not isinstance(data, dict):
        raise MultigraspError(f"config file {path} must hold a mapping of sections (e.g. 'objects:'), not {type(data).__name__}")
    return data


#: Top-level key of a config file that lists files to merge under it (:func:`_read_with_includes`).
INCLUDE_KEY = "include"


def _read_with_includes(path: Path, chain: tuple[Path, ...] = ()) -> dict[str, Any]:
    """The mapping of a config file with its ``include`` list resolved: each listed file (relative to ``path``'s
    folder, itself possibly including others) merged in order, then the file's own keys on top."""
    here = path.resolve()
    data = _anchor_object_paths(_read_yaml(path), path.parent, f"config file {path}")
    includes = data.pop(INCLUDE_KEY, None)
    if includes is None:  # no key, or an empty 'include:'
        includes = []
    elif isinstance(includes, str):
        includes = [includes]
    if not isinstance(includes, list) or not all(isinstance(item, str) for item in includes):
        raise MultigraspError(f"config file {path}: '{INCLUDE_KEY}' must be a file name or a list of file names "
                              "(relative to the file's folder)")
    tree: dict[str, Any] = {}
    for item in includes:
        target = (path.parent / item).resolve()
        if target in chain + (here,):
            raise MultigraspError(f"config file {path}: including '{item}' makes a cycle — remove one of the includes")
        if not target.is_file():
            raise MultigraspError(f"config file {path} includes '{item}', which is not a file — fix the path (relative "
                                  "to the including file's folder)")
        tree = _merge(tree, _read_with_includes(target, chain + (here,)))
    return _merge(tree, data)


def _anchor(value: Any, folder: Path, key: str, source: str) -> Any:
    """``value`` (a path written under ``key`` in ``source``) made absolute: a relative path is read from ``folder``.

    A config file's relative paths are relative to the file, as its ``include`` list is, so a config shipped beside
    its meshes works from any working directory (and in worker processes or Ray nodes started elsewhere).  Until the
    fiftieth session they were read from the working directory; a path that exists only from there is still found,
    with a warning naming the change."""
    if not isinstance(value, (str, Path)) or not str(value):
        return value  # not a path: the config's own validation names it
    path = Path(value).expanduser()
    if path.is_absolute():
        return str(path)
    anchored = (folder / path).resolve()
    if not anchored.exists() and folder.resolve() != Path.cwd().resolve() and path.exists():
        logging.getLogger("multigrasp").warning(
            "%s: %s '%s' is found from the working directory, not from the file's folder (%s); relative paths in a "
            "config file are read from its folder now — write it relative to the file or absolute",
            source, key, value, folder.resolve())
        return str(path.resolve())
    return str(anchored)


def _anchor_object_paths(data: dict[str, Any], folder: Path, source: str) -> dict[str, Any]:
    """``data`` with the file paths it names under ``objects`` (each ``objects.user`` mesh, ``objects.library_file``)
    made absolute from ``folder`` (:func:`_anchor`); anything that is not the expected shape is left for the
    config's validation to report."""
    objects = data.get("objects")
    if not isinstance(objects, dict):
        return data
    objects = dict(objects)
    if "library_file" in objects and objects["library_file"] is not None:
        objects["library_file"] = _anchor(objects["library_file"], folder, "objects.library_file", source)
    if isinstance(objects.get("user"), list):
        objects["user"] = [
            {**item, "mesh": _anchor(item["mesh"], folder, f"objects.user mesh of '{item.get('name', '?')}'", source)}
            if isinstance(item, dict) and "mesh" in item else item
            for item in objects["user"]
        ]
    return {**data, "objects": objects}


def _merge(base: dict[str, Any], update: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in update.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def _known_keys(model: type[Section], prefix: str = "") -> list[str]:
    """Every dotted key of ``model``; the fields of a list's sections (``objects.user``'s meshes) under ``*`` for the
    item's index, as ``objects.user.*.scale``."""
    keys = []
    for name, info in model.model_fields.items():
        keys.append(prefix + name)
        ann = info.annotation
        if isinstance(ann, type) and issubclass(ann, Section):
            keys.extend(_known_keys(ann, prefix + name + "."))
        elif typing.get_origin(ann) is list:
            item, = typing.get_args(ann) or (None,)
            if isinstance(item, type) and issubclass(item, Section):
                keys.extend(_known_keys(item, prefix + name + ".*."))
    return keys


def _closest_key(loc: tuple) -> str | None:
    """The known key nearest an unknown one, with the unknown key's list indices in place of ``*``."""
    pattern = ".".join("*" if isinstance(part, int) else str(part) for part in loc)
    close = difflib.get_close_matches(pattern, _known_keys(PipelineConfig), n=1)
    if not close:
        return None
    indices = iter(str(part) for part in loc if isinstance(part, int))
    return ".".join(next(indices, "0") if part == "*" else part for part in close[0].split("."))


def parse_set(item: str) -> tuple[list[str], Any]:
    """``KEY=VALUE`` of ``--set`` -> (dotted key split, YAML-parsed value); a bad item is a MultigraspError."""
    if "=" not in item:
        raise MultigraspError(f"--set needs KEY=VALUE (e.g. --set run.seed=3), got '{item}'")
    key, raw = item.split("=", 1)
    key = key.strip()
    if not key or any(not part for part in key.split(".")):
        raise MultigraspError(f"--set key '{key}' is not a dotted path like 'scenes.renders'")
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError:
        value = raw
    return key.split("."), value


def _assign(tree: dict[str, Any], path: list[str], value: Any) -> dict[str, Any]:
    update: Any = value
    for part in reversed(path):
        update = {part: update}
    return _merge(tree, update)


def _describe(error: dict[str, Any]) -> str:
    loc = ".".join(str(p) for p in error["loc"])
    if error["type"] == "extra_forbidden":
        close = _closest_key(tuple(error["loc"]))
        hint = f" (did you mean '{close}'?)" if close else ""
        return f"unknown config key '{loc}'{hint} — see `multigrasp run --help` and configs/*.yaml for valid keys"
    value = error.get("input")
    shown = repr(value) if not isinstance(value, dict) else "a mapping"
    message = error["msg"]
    if error["type"] == "value_error":  # a validator's own message: pydantic's prefix is noise, and it may name the value
        message = message.removeprefix("Value error, ")
    got = "" if error["type"] == "value_error" and shown in message else f" (got {shown[:80]})"
    return f"bad value for '{loc}': {message}{got}"


def _describe_first(errors: list[dict[str, Any]]) -> str:
    """The one line for a failed validation: :func:`_describe` of the first error, except that a required key that is
    missing is named as such, with the unknown key beside it where one was given in its place (a user mesh written
    ``{name: mug, path: mug.obj}``: "missing 'objects.user.0.mesh'", not pydantic's "Field required (got a
    mapping)")."""
    first = errors[0]
    if first["type"] != "missing":
        return _describe(first)
    loc, parent = tuple(first["loc"]), tuple(first["loc"][:-1])
    instead = [e for e in errors if e["type"] == "extra_forbidden" and tuple(e["loc"][:-1]) == parent]
    dotted = ".".join(str(p) for p in loc)
    hint = (f"; '{'.'.join(str(p) for p in instead[0]['loc'])}' is not a key there (did you mean '{loc[-1]}'?)"
            if instead else "")
    return f"missing config key '{dotted}' (required){hint} — `multigrasp config --describe` lists every key"


#: What an object's name may hold: it names cache files and stage folders, joins a combination's names with '+'
#: ("cube+mug"), sits between ':' in scene ids ("Pl:cube+mug:0") and between ',' in `generate --objects`.  Checked
#: here, where a config is loaded, not in ``components/objects``: a check there would change every stage's code
#: version, and so the cache key of every finished stage, for no change in what a valid config computes.
OBJECT_NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")


def object_name_problem(name: str) -> str | None:
    """What is wrong with an object's name, with a fix, or None for a name of :data:`OBJECT_NAME_PATTERN`."""
    if OBJECT_NAME_PATTERN.fullmatch(name):
        return None
    fixed = re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_.-") or "my_object"
    return (f"object name {name!r} may hold only letters, digits, '_', '-' and '.', first a letter or digit (it "
            f"names folders and joins combinations); rename it, e.g. {fixed!r}")


def _check_object_names(cfg: PipelineConfig) -> None:
    """The names of the user's meshes and of a custom library file's objects (:func:`object_name_problem`)."""
    for index, user in enumerate(cfg.objects.user):
        problem = object_name_problem(user.name)
        if problem:
            raise MultigraspError(f"bad value for 'objects.user.{index}.name': {problem}")
    library = cfg.objects.library_file
    if library is None or not Path(library).is_file():  # a missing file: the library says so where it is loaded
        return
    from components.objects.library import read_library_file  # its one-line errors for a malformed file

    for name in read_library_file(Path(library)).objects:
        problem = object_name_problem(name)
        if problem:
            raise MultigraspError(f"object library {library}: objects.{name}: {problem}")


def build_config(tree: dict[str, Any]) -> PipelineConfig:
    """Validate a config tree, turning the first pydantic error into a one-line message."""
    try:
        cfg = PipelineConfig.model_validate(tree)
        _check_object_names(cfg)
        return cfg
    except ValidationError as exc:
        raise MultigraspError(_describe_first(exc.errors())) from None
    except MultigraspError:
        raise
    except (ValueError, TypeError) as exc:  # validators of components raising plain errors
        raise MultigraspError(f"bad config: {exc}") from None


def load_config(
    profile: str | None = "smoke",
    config_file: Path | None = None,
    sets: list[str] | None = None,
    **run_overrides: Any,
) -> PipelineConfig:
    """Defaults ← profile ← file ← ``--set`` ← explicit ``run`` overrides (workdir, device, …)."""
    tree: dict[str, Any] = {}
    if profile:
        path = CONFIG_DIR / f"{profile}.yaml"
        if not path.is_file():
            raise MultigraspError(f"unknown profile '{profile}' — choose one of {', '.join(available_profiles())}")
        tree = _merge(tree, _read_with_includes(path))
        tree.setdefault("profile", profile)
    if config_file:
        tree = _merge(tree, _read_with_includes(Path(config_file)))
    for item in sets or []:
        path_parts, value = parse_set(item)
        tree = _assign(tree, path_parts, value)
        if path_parts[0] == "objects":  # paths given on the command line are read from the working directory
            tree = _anchor_object_paths(tree, Path.cwd(), "--set")
    run_updates = {k: v for k, v in run_overrides.items() if v is not None}
    if run_updates:
        tree = _merge(tree, {"run": run_updates})
    return build_config(tree)


def with_overrides(cfg: PipelineConfig, overrides: dict[str, Any]) -> PipelineConfig:
    """``cfg`` with dotted-key overrides applied and validated, as ``--set`` does (ablation variants)."""
    tree = cfg.model_dump(mode="json")
    for key, value in overrides.items():
        tree = _assign(tree, key.split("."), value)
    return build_config(tree)


def section_digest(cfg: PipelineConfig, *sections: str, extra: Any = None) -> str:
    """Digest of the named config sections (dotted paths), the part of a cache key from config.

    With ``objects`` among them, the contents of the files the config names there (:func:`object_file_digests`)
    count too, so a user mesh edited in place keys new units instead of serving those of the old geometry.  A user
    mesh that no split uses (:meth:`ObjectsConfig.used_only`) counts for nothing: a mesh added to ``objects.user`` only, to
    ``generate`` grasps for it (and ``--lift`` them), keeps every trained stage."""
    from tasks.artifacts import digest

    dump = _with_used_user_meshes(cfg.model_dump(mode="json"), cfg.objects)
    picked = {}
    for name in sections:
        node: Any = dump
        for part in name.split("."):
            node = node[part]
        picked[name] = node
    files = object_file_digests(cfg.objects) if "objects" in sections else {}
    if files:  # only configs that name files: every other key stays as it was before files counted
        picked["objects.files"] = files
    return digest({"sections": picked, "extra": extra})


#: ``run`` fields that say how or where an invocation runs, not what it computes (left out of :func:`evaluation_key`;
#: evaluations in worker processes give the same outcomes as in one, tests/test_flows.py).
_HOW_TO_RUN = ("workdir", "runner", "max_workers", "torch_threads", "ray_address", "malloc_mmap_threshold_mb",
               "malloc_trim_threshold_mb")
#: ``specialists`` fields that say how an evaluation's lifts are split into jobs, not what they compute.
_HOW_TO_EVALUATE = ("eval_chunk_poses",)


#: results file → the config sections its evaluation never reads (neither directly nor through the stage outputs it
#: lifts or scores), left out of its :func:`evaluation_key`: pre-grasp quality does not depend on the lift, and the
#: synthesised pre-grasps' lifts do not depend on the generator.
EVALUATION_IGNORES: dict[str, tuple[str, ...]] = {
    "pregrasp_synthetic.json": ("generator", "pointnet", "specialists", "lift", "reach", "curriculum", "distill"),
    "pregrasp_generated.json": ("pointnet", "specialists", "lift", "reach", "curriculum", "distill"),
    "ablation_generator.json": ("pointnet", "specialists", "lift", "reach", "curriculum", "distill"),
    "execution.json": ("generator", "curriculum", "distill"),
    "ablation_execution.json": ("generator", "curriculum", "distill"),
    "execution_generated.json": ("curriculum", "distill"),
    "execution_generalist.json": (),
    "ablation_curriculum.json": ("distill",),
}


def evaluation_key(cfg: PipelineConfig, results_file: str) -> str:
    """Digest of every setting the figures of ``results_file`` can depend on: the config (with the contents of the
    object files it names) except where and how it runs (``run.workdir``, the runner and its workers), MLflow's
    settings and the sections that evaluation never reads (:data:`EVALUATION_IGNORES`).  ``evaluate`` writes it
    into each results file as ``config_key``; ``status`` and ``run --evaluate`` call a results file current only
    while it matches (its stage outputs are checked too)."""
    from tasks.artifacts import digest

    return digest({"config": evaluation_settings(cfg, results_file), "objects.files": object_file_digests(cfg.objects)})


def results_stamp(cfg: PipelineConfig, results_file: str) -> dict[str, str]:
    """The fields every results file carries besides its rows: ``config_key`` (:func:`evaluation_key`) and
    ``evaluated_at``, when it was written (UTC, ISO 8601, seconds).  ``report`` shows the latter, so a work dir
    copied without its files' times (plain ``cp -r``, a download) still says when each table was evaluated."""
    import datetime

    now = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0)
    return {"config_key": evaluation_key(cfg, results_file), "evaluated_at": now.isoformat()}


def evaluation_settings(cfg: PipelineConfig, results_file: str) -> dict[str, Any]:
    """The part of the config that :func:`evaluation_key` digests for ``results_file`` (a JSON tree); an evaluation's
    MLflow run holds it, flattened, as its params."""
    if results_file not in EVALUATION_IGNORES:
        raise ValueError(f"unknown results file {results_file!r}")
    dump = _with_used_user_meshes(cfg.model_dump(mode="json"), cfg.objects)
    for section in ("tracking", *EVALUATION_IGNORES[results_file]):
        dump.pop(section, None)
    dump["run"] = {k: v for k, v in dump["run"].items() if k not in _HOW_TO_RUN}
    if "specialists" in dump:
        dump["specialists"] = {k: v for k, v in dump["specialists"].items() if k not in _HOW_TO_EVALUATE}
    return dump


def _with_used_user_meshes(dump: dict[str, Any], objects: ObjectsConfig) -> dict[str, Any]:
    """A config dump whose ``objects`` section is :meth:`ObjectsConfig.key_dump`: only the user meshes a split uses,
    files named by their contents (:func:`object_file_digests`), not by where they lie, so a config and its meshes
    moved to another folder or machine (a cluster's mount, a laptop's copy of the work dir) keep their keys."""
    return {**dump, "objects": objects.key_dump()}


def object_file_digests(objects: ObjectsConfig) -> dict[str, str]:
    """sha256 of each user mesh file a split uses (``objects.user``, :meth:`ObjectsConfig.used_only`; from the working
    directory when not absolute), of a custom ``objects.library_file`` and of the mesh files it names (from its
    folder; the installed ``pybullet_data`` meshes of the default library are not hashed), each under a name that
    does not depend on where it lies: ``user:<object name>``, ``library_file``, ``library:<source as written in
    the library>``; ``missing`` for a file that is not there (the library's own check then names it)."""
    from components.objects.library import PYBULLET_DATA_PREFIX, read_library_file, resolve_source
    from components.objects.shapes import MeshShape

    named = {f"user:{user.name}": Path(user.mesh).expanduser() for user in objects.used_only().user}
    if objects.library_file is not None:
        library = Path(objects.library_file).expanduser()
        library = library if library.is_absolute() else Path.cwd() / library
        named["library_file"] = library
        try:
            specs = read_library_file(library).objects.values() if library.is_file() else []
        except MultigraspError:  # the library's own check names the problem when the stage builds it
            specs = []
        for spec in specs:
            if isinstance(spec.shape, MeshShape):
                for source in (spec.shape.source, spec.shape.collision):
                    if source and not source.startswith(PYBULLET_DATA_PREFIX):
                        named[f"library:{source}"] = resolve_source(source, library.parent)
    out = {}
    for written, path in named.items():
        path = path if path.is_absolute() else Path.cwd() / path
        try:
            stat = path.stat()
        except OSError:
            out[written] = "missing"
            continue
        out[written] = _file_sha256(str(path.resolve()), stat.st_mtime_ns, stat.st_size)
    return out


@functools.lru_cache(maxsize=256)
def _file_sha256(path: str, mtime_ns: int, size: int) -> str:
    """sha256 of a file's bytes, memoised by its identity (path, modification time, size): the stage plans ask for
    it once per unit, and a scan is tens of MB."""
    from components.fileio import sha256_file

    return sha256_file(Path(path))


# --------------------------------------------------------------------------- printing a config

#: Width of the description comments of :func:`config_yaml`.
DESCRIBE_WIDTH = 100


def config_yaml(cfg: PipelineConfig, key: str | None = None, describe: bool = False) -> str:
    """``cfg`` (or its part under the dotted ``key``) as YAML that ``--config`` reads back into the same config:
    sections as nested blocks, every other value on one line in JSON's flow syntax (which YAML reads); with
    ``describe``, each field's description as a comment above it.  An unknown key is a one-line error naming the
    nearest known one."""
    node: Any = cfg
    path: list[str] = []
    for part in key.split(".") if key else []:
        if isinstance(node, Section) and part in type(node).model_fields:
            node = _portable(node, part, getattr(node, part))
        elif isinstance(node, (list, tuple)) and part.isdigit() and int(part) < len(node):
            node = node[int(part)]
        else:
            loc = tuple(int(p) if p.isdigit() else p for p in [*path, part])
            close = _closest_key(loc)
            hint = f" (did you mean '{close}'?)" if close else ""
            raise MultigraspError(f"unknown config key '{key}'{hint} — `multigrasp config` prints every key")
        path.append(part)
    lines: list[str] = []
    if isinstance(node, Section):
        _section_lines(node, 0, describe, lines)
        text = "\n".join(lines)
        for part in reversed(path):  # nest the part under its key, so the output is still a --config file
            text = f"{part}:\n" + "\n".join("  " + line if line else line for line in text.splitlines())
        return text + "\n"
    return _nest(path, _flow(_plain(node))) + "\n"


def _nest(path: list[str], value: str) -> str:
    """``a.b.c = v`` as ``a:\\n  b:\\n    c: v`` (a list index stays a key: the value of one list item)."""
    lines = [f"{'  ' * depth}{part}:" for depth, part in enumerate(path[:-1])]
    return "\n".join([*lines, f"{'  ' * (len(path) - 1)}{path[-1]}: {value}" if path else value])


def _section_lines(section: Section, depth: int, describe: bool, lines: list[str]) -> None:
    import textwrap

    indent = "  " * depth
    for name, info in type(section).model_fields.items():
        value = getattr(section, name)
        if describe and info.description:
            lines.extend(f"{indent}# {line}" for line in textwrap.wrap(info.description, DESCRIBE_WIDTH - len(indent)))
        if isinstance(value, Section):
            lines.append(f"{indent}{name}:")
            _section_lines(value, depth + 1, describe, lines)
        else:
            lines.append(f"{indent}{name}: {_flow(_plain(_portable(section, name, value)))}")


def _portable(section: Section, name: str, value: Any) -> Any:
    """``run.workdir`` under the working directory as a relative path, which a config file means the same way
    (``./runs`` wherever the command runs), so a printed config does not pin the folder it was printed in."""
    if isinstance(section, RunConfig) and name == "workdir":
        try:
            return Path(value).relative_to(Path.cwd())
        except ValueError:
            return value
    return value


def _plain(value: Any) -> Any:
    """A field's value as JSON-ready data (sections inside lists as dicts, paths as strings)."""
    if isinstance(value, Section):
        return value.model_dump(mode="json")
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, Path):
        return str(value)
    return value


def _flow(value: Any) -> str:
    """One value on one line, in PyYAML's flow style (which quotes strings that would read as something else, and
    writes a float so that it reads back as one: ``1.0e-06``, not ``1e-06``, which YAML 1.1 reads as a string)."""
    text = yaml.safe_dump(value, default_flow_style=True, width=float("inf"), sort_keys=False, allow_unicode=True)
    return text.removesuffix("\n...\n").strip()
