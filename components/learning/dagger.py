"""DAgger distillation of the state-based specialists into one vision-based generalist (paper §"Learning a Generalist
from Specialists", DAgger paragraph; Ross, Gordon & Bagnell 2011).

The student observes what a real set-up has: the hand's own blocks of the lift observation (joint angles, velocities
and torques, fingertip wrenches, the palm's state, the last action, the joint and palm goals and residues, the hand's
point-cloud feature: :func:`student_blocks`) and, instead of every object block (state, pose goal and residue,
feature: the entries the paper marks with *), one PointNet feature of the scene cloud seen by three cameras
(:mod:`components.learning.vision`).  Its size does not depend on the number of objects, so one student serves every
bin.  Its action is the lift env's 24-D action.

Each DAgger iteration k:

1. rolls out ``episodes_per_iteration`` episodes, each in a bin drawn in proportion to its pre-grasps; in an episode
   the teacher (the bin's specialist, deterministic) acts with probability beta_k = ``beta_start`` x
   ``beta_decay`` ^ k, else the student (the usual per-episode mixture; beta_0 = 1: the first data are the teachers'
   own trajectories);
2. labels every visited state with the teacher's action there, whoever acted;
3. aggregates the pairs into the data set (at most ``max_samples``, the oldest dropped first) and
4. fits the student to all of it: ``epochs`` passes of minibatch Adam on the mean squared error to the teachers'
   actions, with the input normalised by the data set's mean and std.

Every ``validate_every`` iterations the deterministic student lifts the validation pre-grasps; the best validated
student is the generalist (as the specialists keep their best validated actor).  The checkpoint (student,
optimiser, iteration, history, best) is written atomically after every iteration, after that iteration's pairs
(:func:`data_folder`): a killed distillation resumes from its last finished iteration with its whole data set, and
a finished one returns at once.
"""

from __future__ import annotations

import copy
import io
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np
import torch
from pydantic import Field
from tensordict import TensorDictBase
from torch import nn
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MLP

from components.config_base import Section
from components.errors import MultigraspError
from components.execution.lift_config import LiftEnvConfig
from components.execution.observations import observation_blocks
from components.fileio import atomic_write_bytes
from components.learning.vision import SceneCameras

class DAggerConfig(Section):
    """DAgger of the generalist: data collection, the student network and its fit."""

    iterations: int = Field(10, ge=1, description="DAgger iterations (collect, aggregate, fit).")
    episodes_per_iteration: int = Field(16, ge=1, description="Episodes rolled out per iteration, over all bins.")
    beta_start: float = Field(1.0, ge=0.0, le=1.0, description="Probability that the teacher acts in an episode of the first iteration (1: the teachers' own trajectories first).")
    beta_decay: float = Field(0.5, ge=0.0, le=1.0, description="beta_k = beta_start x beta_decay^k: the teachers hand over to the student.")
    hidden: list[int] = Field(default_factory=lambda: [512, 256], description="Hidden widths of the student MLP (ELU).")
    lr: float = Field(3e-4, gt=0.0, description="Adam learning rate of the student.")
    epochs: int = Field(20, ge=1, description="Passes over the aggregated data set per iteration.")
    minibatch_size: int = Field(256, ge=1, description="Samples per gradient step.")
    max_samples: int = Field(200_000, ge=1, description="Largest data set kept (state-action pairs); the oldest pairs are dropped first.")
    validate_every: int = Field(1, ge=0, description="Lift the validation pre-grasps with the deterministic student every this many iterations (0: never; the last student is kept).")
    seed: int = Field(0, ge=0, description="Seed of the student's initialisation, the episodes' draws and the minibatches.")


def student_blocks(cfg: LiftEnvConfig) -> list[tuple[str, int]]:
    """The blocks of the lift observation the student keeps: every block before the first object block (the hand's
    own; :func:`components.execution.observations.observation_blocks` with no object)."""
    return observation_blocks(cfg, 0)


def hand_dim(cfg: LiftEnvConfig) -> int:
    return sum(d for _, d in student_blocks(cfg))


def student_dim(cfg: LiftEnvConfig) -> int:
    """Size of the student's observation: the hand blocks and one scene feature."""
    return hand_dim(cfg) + cfg.feature_dim


class StudentPolicy(nn.Module):
    """action = tanh(MLP((x - mean) / std)): a deterministic policy in the lift env's action box [-1, 1]^24.  The
    normaliser's statistics are buffers, set from the data set before each fit (:meth:`set_normaliser`)."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: Sequence[int]):
        super().__init__()
        self.register_buffer("mean", torch.zeros(obs_dim))
        self.register_buffer("std", torch.ones(obs_dim))
        self.net = MLP(in_features=obs_dim, out_features=act_dim, num_cells=list(hidden), activation_class=nn.ELU)

    def set_normaliser(self, observations: torch.Tensor) -> None:
        self.mean.copy_(observations.mean(0))
        self.std.copy_(observations.std(0, unbiased=False).clamp_min(1e-3))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self.net(((obs - self.mean) / self.std).clamp(-10.0, 10.0)))


class StudentObserver:
    """The student's observation in one lift env: the hand blocks of the env's observation and the scene feature,
    recomputed at every episode start and every ``lift.feature_period`` steps (as the env's own features)."""

    def __init__(self, env, cameras: SceneCameras):
        self.env, self.cameras = env, cameras
        self.hand_dim = hand_dim(env.cfg)
        self._feature: Optional[np.ndarray] = None

    def __call__(self, td: TensorDictBase) -> torch.Tensor:
        t = self.env.episode.t
        if self._feature is None or t % self.env.cfg.feature_period == 0:
            self._feature = self.cameras.feature(self.env.world, self.env.featurizer.features)
        hand = td["observation"][..., : self.hand_dim]
        return torch.cat([hand, torch.from_numpy(self._feature).to(hand)], dim=-1)


class VisionPolicy:
    """The student as a lift-env policy (TensorDict -> TensorDict writing ``action``): what evaluation and GIFs run."""

    def __init__(self, student: StudentPolicy, observer: StudentObserver):
        self.student, self.observer = student, observer

    def __call__(self, td: TensorDictBase) -> TensorDictBase:
        with torch.no_grad():
            action = self.student(self.observer(td))
        return td.set("action", action)


class MixturePolicy:
    """DAgger's behaviour policy in one env: per episode the teacher acts with probability ``beta``, else the student;
    every step's student observation and teacher action are appended to ``observations`` / ``labels``."""

    def __init__(self, teacher, student: StudentPolicy, observer: StudentObserver, beta: float, rng: np.random.Generator):
        self.teacher, self.student, self.observer = teacher, student, observer
        self.beta, self.rng = beta, rng
        self.teacher_acts = True
        self.observations: list[torch.Tensor] = []
        self.labels: list[torch.Tensor] = []

    def __call__(self, td: TensorDictBase) -> TensorDictBase:
        if self.observer.env.episode.t == 0:
            self.teacher_acts = bool(self.rng.random() < self.beta)
        obs = self.observer(td)
        label = self.teacher(td.clone())["action"].detach()
        self.observations.append(obs.detach().clone())
        self.labels.append(label.clone())
        if self.teacher_acts:
            return td.set("action", label)
        with torch.no_grad():
            return td.set("action", self.student(obs))


@dataclass
class Bin:
    """One specialist's bin as DAgger sees it: its env (over the bin's pre-grasps) and its deterministic teacher."""

    label: str
    env: object
    teacher: Callable[[TensorDictBase], TensorDictBase]
    weight: float = 1.0


@dataclass
class DAggerResult:
    student: StudentPolicy
    history: list[dict] = field(default_factory=list)
    validations: list[dict] = field(default_factory=list)
    best: Optional[dict] = None
    resumed_from: int = 0
    samples: int = 0


#: progress(iteration, total, row) after every iteration (row: samples, loss, beta, val_success, eta_s, ...).
ProgressFn = Callable[[int, int, dict], None]
#: validate(policy_for_env) -> {"success", "lift"}: policy_for_env(env) gives the student's policy in that env.
ValidateFn = Callable[[Callable[[object], Callable]], dict]


def load_checkpoint(path: Path) -> dict:
    """The distillation checkpoint dict (one-line error if it is not a readable one)."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # noqa: BLE001 -- any unreadable file gets the same advice
        raise MultigraspError(f"DAgger checkpoint {path} is corrupt ({type(exc).__name__}); delete it to distil "
                              "again from scratch") from None
    if not isinstance(state, dict) or state.get("format") != "multigrasp-dagger":
        raise MultigraspError(f"{path} is not a DAgger checkpoint of this project; delete it to distil again")
    return state


def load_student(path: Path, which: str = "best") -> StudentPolicy:
    """The student of a checkpoint: ``best`` (the best validated one; the last without validation) or ``last``."""
    state = load_checkpoint(Path(path))
    student = StudentPolicy(state["obs_dim"], state["act_dim"], state["config"]["hidden"])
    best = state.get("best")
    student.load_state_dict(best["student"] if which == "best" and best is not None else state["student"])
    return student.eval()


def _save(path: Path, student: StudentPolicy, optimizer, cfg: DAggerConfig, iteration: int, history, validations,
          best) -> None:
    buffer = io.BytesIO()
    torch.save({"format": "multigrasp-dagger", "version": 1, "config": cfg.model_dump(mode="json"),
                "obs_dim": student.mean.shape[0], "act_dim": student.net[-1].out_features,
                "student": student.state_dict(), "optimizer": optimizer.state_dict(), "iteration": iteration,
                "history": history, "validations": validations, "best": best}, buffer)
    atomic_write_bytes(path, buffer.getvalue())


def data_folder(checkpoint: Path) -> Path:
    """Where the data set of a checkpoint lies: one file per iteration (``iteration-0001.pt``: that iteration's
    student observations and teacher actions) in ``<checkpoint name>.data/`` beside it.  Each iteration writes only
    its own pairs, so a checkpoint stays small whatever the data set's size (2 M pairs of 718 floats are ~5.7 GB)."""
    return checkpoint.with_name(checkpoint.name + ".data")


def _save_chunk(checkpoint: Path, iteration: int, observations: torch.Tensor, labels: torch.Tensor) -> None:
    buffer = io.BytesIO()
    torch.save({"observations": observations, "labels": labels}, buffer)
    atomic_write_bytes(data_folder(checkpoint) / f"iteration-{iteration:04d}.pt", buffer.getvalue())


def _load_data(checkpoint: Path, iterations: int, obs_dim: int, act_dim: int,
               max_samples: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The data set of the first ``iterations`` iterations (the newest ``max_samples`` pairs); one-line error for a
    missing or unreadable chunk."""
    observations, labels = [torch.zeros(0, obs_dim)], [torch.zeros(0, act_dim)]
    for number in range(1, iterations + 1):
        path = data_folder(checkpoint) / f"iteration-{number:04d}.pt"
        try:
            chunk = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as exc:  # noqa: BLE001 -- any unreadable file gets the same advice
            raise MultigraspError(f"DAgger data {path} is missing or corrupt ({type(exc).__name__}); delete "
                                  f"{checkpoint} and {data_folder(checkpoint)} to distil again from scratch") from None
        observations.append(chunk["observations"])
        labels.append(chunk["labels"])
    return torch.cat(observations)[-max_samples:], torch.cat(labels)[-max_samples:]


def fit_student(student: StudentPolicy, optimizer, observations: torch.Tensor, labels: torch.Tensor,
                cfg: DAggerConfig, generator: torch.Generator) -> float:
    """``epochs`` passes of minibatch Adam on mean((student(x) - a_teacher)^2); the normaliser is set from the data
    set first.  -> the last epoch's mean loss."""
    student.set_normaliser(observations)
    student.train()
    n, last = len(observations), 0.0
    for _ in range(cfg.epochs):
        order = torch.randperm(n, generator=generator)
        total, count = 0.0, 0
        for first in range(0, n, cfg.minibatch_size):
            batch = order[first: first + cfg.minibatch_size]
            loss = torch.mean((student(observations[batch]) - labels[batch]) ** 2)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            total += float(loss.detach()) * len(batch)
            count += len(batch)
        last = total / max(count, 1)
    student.eval()
    return last


def beta(cfg: DAggerConfig, iteration: int) -> float:
    """Probability that the teacher acts in an episode of iteration ``iteration`` (0-based)."""
    return cfg.beta_start * cfg.beta_decay ** iteration


def _validate(validate: ValidateFn, student: StudentPolicy, cameras: SceneCameras, iteration: int,
              best: Optional[dict]) -> tuple[dict, Optional[dict]]:
    start = time.perf_counter()
    scores = validate(lambda env: VisionPolicy(student, StudentObserver(env, cameras)))
    row = {"iteration": iteration, "success": float(scores["success"]), "lift": float(scores["lift"]),
           "validate_s": round(time.perf_counter() - start, 3)}
    if best is None or (row["success"], row["lift"]) > (best["success"], best["lift"]):
        best = {**row, "student": copy.deepcopy(student.state_dict())}
    return row, best


def run_dagger(bins: Sequence[Bin], cameras: SceneCameras, cfg: DAggerConfig, checkpoint: Path,
               progress: Optional[ProgressFn] = None, validate: Optional[ValidateFn] = None) -> DAggerResult:
    """Distil the bins' teachers into one student (module docstring), resuming from ``checkpoint`` when it exists."""
    if not bins:
        raise MultigraspError("DAgger got no specialists to distil; run the specialists stage first "
                              "(multigrasp run --until specialists)")
    lift_cfg = bins[0].env.cfg
    torch.manual_seed(cfg.seed)
    student = StudentPolicy(student_dim(lift_cfg), bins[0].env.action_spec.shape[-1], cfg.hidden)
    optimizer = torch.optim.Adam(student.parameters(), lr=cfg.lr)
    start_iteration, history, validations, best = 0, [], [], None
    observations = torch.zeros(0, student.mean.shape[0])
    labels = torch.zeros(0, student.net[-1].out_features)
    checkpoint = Path(checkpoint)
    if checkpoint.exists():
        state = load_checkpoint(checkpoint)
        try:
            student.load_state_dict(state["student"])
        except RuntimeError:
            raise MultigraspError(f"DAgger checkpoint {checkpoint} does not fit this student's sizes; delete it to "
                                  "distil again") from None
        optimizer.load_state_dict(state["optimizer"])
        start_iteration, history = int(state["iteration"]), list(state["history"])
        validations, best = list(state["validations"]), state["best"]
        observations, labels = _load_data(checkpoint, start_iteration, observations.shape[1], labels.shape[1],
                                          cfg.max_samples)
    result = DAggerResult(student=student, history=history, validations=validations, resumed_from=start_iteration)
    validating = validate is not None and cfg.validate_every > 0
    weights = np.array([b.weight for b in bins], dtype=np.float64)
    weights = weights / weights.sum()
    observers = [StudentObserver(b.env, cameras) for b in bins]
    began = time.perf_counter()
    for iteration in range(start_iteration, cfg.iterations):
        rng = np.random.default_rng([cfg.seed, iteration])
        generator = torch.Generator().manual_seed(cfg.seed * 100_003 + iteration)
        for b in bins:
            b.env.set_seed(int(rng.integers(2**31)))
        p_teacher = beta(cfg, iteration)
        collect_start = time.perf_counter()
        new_obs, new_labels, successes, episodes = [], [], 0, 0
        with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
            for _ in range(cfg.episodes_per_iteration):
                which = int(rng.choice(len(bins), p=weights))
                b = bins[which]
                mixture = MixturePolicy(b.teacher, student, observers[which], p_teacher, rng)
                rollout = b.env.rollout(b.env.cfg.max_steps, policy=mixture, break_when_any_done=True)
                successes += int(bool(rollout[-1]["next", "success"]))
                episodes += 1
                new_obs += mixture.observations
                new_labels += mixture.labels
        new_obs, new_labels = torch.stack(new_obs), torch.stack(new_labels)
        _save_chunk(checkpoint, iteration + 1, new_obs, new_labels)  # before the checkpoint that counts it
        observations = torch.cat([observations, new_obs])[-cfg.max_samples:]
        labels = torch.cat([labels, new_labels])[-cfg.max_samples:]
        fit_start = time.perf_counter()
        loss = fit_student(student, optimizer, observations, labels, cfg, generator)
        done = time.perf_counter()
        row = {"iteration": iteration + 1, "beta": round(p_teacher, 6), "samples": len(observations),
               "new_samples": len(new_obs), "episodes": episodes, "behaviour_success": successes / max(episodes, 1),
               "loss": loss, "collect_s": round(fit_start - collect_start, 3), "fit_s": round(done - fit_start, 3)}
        number = iteration + 1
        if validating and (number % cfg.validate_every == 0 or number == cfg.iterations):
            check, best = _validate(validate, student, cameras, number, best)
            validations.append(check)
            row.update(val_success=check["success"], val_lift=check["lift"])
        history.append(row)
        _save(checkpoint, student, optimizer, cfg, number, history, validations, best)
        if progress is not None:
            elapsed = time.perf_counter() - began
            progress(number, cfg.iterations,
                     {**row, "eta_s": elapsed / (number - start_iteration) * (cfg.iterations - number)})
    result.best = None if best is None else {k: v for k, v in best.items() if k != "student"}
    result.samples = len(observations)
    return result
