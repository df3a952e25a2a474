"""Training the grasp generator on a :class:`~components.generation.dataset.GraspDataset`, with checkpoints
and resume (DESIGN §5.2)::

    result = train_generator(dataset, cfg, Path("generator.pt"), progress=print)
    model = load_generator(Path("generator.pt"))          # ready to sample / generate_grasps

* **Loss.**  AdamW (``cfg.lr``, ``cfg.weight_decay``) on :meth:`GraspGenerator.loss` (epsilon- or v-MSE,
  ``cfg.prediction``, of the standardised representation), gradients clipped to ``cfg.grad_clip``.
* **Standardiser.**  Fitted once on all of the dataset's x_0 before the first step, then kept (it is part
  of the model's state and is also stored on its own in the checkpoint).
* **Randomness.**  Weights are initialised under ``torch.manual_seed(cfg.seed)``; step s draws its minibatch
  (without replacement inside a batch), timesteps and noise from a generator seeded with (cfg.seed, s), and
  dropout from the global RNG reseeded the same way -- so a run interrupted and resumed at any checkpoint
  ends with the same weights as an uninterrupted one (same device and threads).  The caller's global RNG
  state is restored afterwards.
* **Checkpoint.**  {format, version, model, optimizer, standardizer, step, history, running, config} written
  atomically (temp file + rename) every ``cfg.checkpoint_every`` steps and at the end.  Calling
  :func:`train_generator` again with the same path resumes from its step (a finished one returns at once);
  ``train_steps`` may be raised to train on (:func:`extendable_step` says whether a checkpoint can seed a
  longer training).  An unreadable file, or one trained with a different model
  config, is a one-line error naming the file to delete.
* **History.**  One row {step, loss (mean since the last row), seconds (of training, over
  all calls)} every ``cfg.log_every`` steps and at
  the last step; ``progress(step, total, row + eta_s)`` is called with each row.
"""

from __future__ import annotations

import io
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

import torch
from torch import nn

from components.errors import MultigraspError
from components.fileio import atomic_write_bytes
from components.generation.config import GeneratorConfig
from components.generation.dataset import GraspDataset
from components.generation.generator import GraspGenerator

FORMAT = "multigrasp-generator"
VERSION = 1
TRAIN_COMMAND = "multigrasp run --until train-generator"
#: config fields that may change between a checkpoint and its resumption
RESUMABLE_FIELDS = frozenset({"train_steps", "log_every", "checkpoint_every"})

#: progress(step, total, info)
ProgressFn = Callable[[int, int, dict], None]


@dataclass
class TrainResult:
    generator: GraspGenerator
    history: list[dict] = field(default_factory=list)
    resumed_from: int = 0  # steps found in the checkpoint at start


def _step_seed(seed: int, step: int) -> int:
    return (int(seed) * 1_000_003 + int(step)) % (2**63 - 1)


def build_generator(cfg: GeneratorConfig) -> GraspGenerator:
    """A fresh GraspGenerator with weights initialised under ``cfg.seed`` (the global RNG is left untouched)."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(cfg.seed)
        return GraspGenerator(cfg)


def load_checkpoint(path: Path) -> dict:
    """The checkpoint dict (one-line error naming the file to delete if it is not a readable generator checkpoint)."""
    path = Path(path)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 -- any unreadable file gets the same advice
        raise MultigraspError(f"generator checkpoint {path} is corrupt ({type(exc).__name__}); delete it to retrain "
                              f"from scratch ({TRAIN_COMMAND})") from None
    if not isinstance(state, dict) or state.get("format") != FORMAT or state.get("version") != VERSION:
        raise MultigraspError(f"{path} is not a grasp-generator checkpoint of this project (format "
                              f"{FORMAT} v{VERSION}); delete it to retrain ({TRAIN_COMMAND})")
    return state


def _save(path: Path, model: GraspGenerator, optimizer, step: int, history: list, running: tuple[float, int],
          cfg: GeneratorConfig) -> None:
    buffer = io.BytesIO()
    torch.save({"format": FORMAT, "version": VERSION,
                "model": {k: v.detach().cpu() for k, v in model.state_dict().items()},
                "optimizer": optimizer.state_dict(),
                "standardizer": {"mean": model.standardizer.mean.detach().cpu(),
                                 "std": model.standardizer.std.detach().cpu()},
                "step": step, "history": history, "running": [float(running[0]), int(running[1])],
                "config": cfg.model_dump(mode="json")}, buffer)
    atomic_write_bytes(path, buffer.getvalue())


def _config_of(state: dict, path: Path) -> GeneratorConfig:
    try:
        return GeneratorConfig(**state["config"])
    except Exception:  # noqa: BLE001
        raise MultigraspError(f"generator checkpoint {path} holds a config this version cannot read; delete it to "
                              f"retrain ({TRAIN_COMMAND})") from None


def _check_same_model(saved: GeneratorConfig, cfg: GeneratorConfig, path: Path) -> None:
    a, b = saved.model_dump(mode="json"), cfg.model_dump(mode="json")
    changed = sorted(k for k in set(a) | set(b) if k not in RESUMABLE_FIELDS and a.get(k) != b.get(k))
    if changed:
        raise MultigraspError(f"generator checkpoint {path} was trained with a different generator config "
                              f"({', '.join(changed)}); delete it to retrain with the new one")


def extendable_step(path: Path, cfg: GeneratorConfig) -> Optional[int]:
    """The step of the checkpoint at ``path`` if training it on to ``cfg.train_steps`` is the same as training
    ``cfg`` from scratch: its config equals ``cfg`` apart from :data:`RESUMABLE_FIELDS` and its step is at most
    ``cfg.train_steps``.  None otherwise, or when the file is missing or unreadable (a search, not an error)."""
    try:
        state = load_checkpoint(path)
        saved, step = _config_of(state, path), int(state["step"])
    except (MultigraspError, KeyError, TypeError, ValueError):
        return None
    try:
        _check_same_model(saved, cfg, path)
    except MultigraspError:
        return None
    return step if step <= cfg.train_steps else None


def _restore(model: GraspGenerator, state: dict, path: Path) -> None:
    try:
        model.load_state_dict(state["model"])
        model.standardizer.mean.copy_(state["standardizer"]["mean"])
        model.standardizer.std.copy_(state["standardizer"]["std"])
    except (KeyError, RuntimeError, TypeError):
        raise MultigraspError(f"generator checkpoint {path} does not fit the generator's network; delete it to "
                              f"retrain ({TRAIN_COMMAND})") from None


def train_generator(dataset: GraspDataset, cfg: GeneratorConfig, checkpoint_path: Path,
                    progress: Optional[ProgressFn] = None, device="cpu") -> TrainResult:
    """Train (or resume) the grasp generator on ``dataset`` for ``cfg.train_steps`` steps (module docstring)."""
    checkpoint_path = Path(checkpoint_path)
    device = torch.device(device)
    if len(dataset) == 0:
        raise MultigraspError("no grasps to train on; the synthesis stage accepted none")
    built = dataset.cfg
    if built.representation != cfg.representation or built.points_per_object != cfg.points_per_object \
            or built.max_objects > cfg.max_objects:
        raise MultigraspError("the generator's training data were built for another generator config "
                              "(representation / points_per_object / max_objects); rebuild the GraspDataset with this one")

    model = build_generator(cfg)
    state = None
    if checkpoint_path.exists():
        state = load_checkpoint(checkpoint_path)
        _check_same_model(_config_of(state, checkpoint_path), cfg, checkpoint_path)
        _restore(model, state, checkpoint_path)
    else:
        model.standardizer.fit(dataset.x0.to(model.standardizer.mean.dtype))
    model.to(device)
    optimizer = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    step, history, running = 0, [], (0.0, 0)
    if state is not None:
        try:
            optimizer.load_state_dict(state["optimizer"])
            step, history = int(state["step"]), list(state["history"])
            running = (float(state["running"][0]), int(state["running"][1]))
        except (KeyError, ValueError, TypeError, IndexError):
            raise MultigraspError(f"generator checkpoint {checkpoint_path} is incomplete; delete it to retrain "
                                  f"({TRAIN_COMMAND})") from None
    result = TrainResult(generator=model, history=history, resumed_from=step)
    total = cfg.train_steps
    if step >= total:
        model.eval()
        return result

    n, batch_size = len(dataset), cfg.batch_size
    start, first = time.perf_counter(), step
    before = float(history[-1]["seconds"]) if history else 0.0  # training time of earlier calls
    loss_sum, loss_count = running
    model.train()
    with torch.random.fork_rng(devices=[device] if device.type == "cuda" else []):
        while step < total:
            step += 1
            seed = _step_seed(cfg.seed, step)
            torch.manual_seed(seed)  # dropout (if any)
            generator = torch.Generator().manual_seed(seed)
            if batch_size <= n:
                indices = torch.randperm(n, generator=generator)[:batch_size]
            else:
                indices = torch.randint(n, (batch_size,), generator=generator)
            x0, objects = dataset.batch(indices, device=device)
            loss = model.loss(x0, objects, generator)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            if cfg.grad_clip > 0:
                nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
            optimizer.step()
            value = float(loss.detach())
            if not torch.isfinite(torch.tensor(value)):
                raise MultigraspError(f"the generator's training loss became {value} at step {step}; lower "
                                      f"generator.lr (now {cfg.lr:g}) and delete {checkpoint_path} to retrain")
            loss_sum, loss_count = loss_sum + value, loss_count + 1
            if step % cfg.log_every == 0 or step == total:
                elapsed = time.perf_counter() - start
                row = {"step": step, "loss": loss_sum / loss_count, "seconds": before + elapsed}
                history.append(row)
                loss_sum, loss_count = 0.0, 0
                if progress is not None:
                    progress(step, total, {**row, "eta_s": elapsed / (step - first) * (total - step)})
            if step % cfg.checkpoint_every == 0 or step == total:
                _save(checkpoint_path, model, optimizer, step, history, (loss_sum, loss_count), cfg)
    model.eval()
    return result


def load_generator(path: Path, device="cpu") -> GraspGenerator:
    """The trained generator of a checkpoint (eval mode, its standardiser restored), on ``device``."""
    path = Path(path)
    if not path.exists():
        raise MultigraspError(f"no trained grasp generator at {path}; train it first with `{TRAIN_COMMAND}`")
    state = load_checkpoint(path)
    model = build_generator(_config_of(state, path))
    _restore(model, state, path)
    return model.to(device).eval()
