"""Which pre-grasp a training episode starts from (``LiftEnvConfig.start_sampling``).

``uniform``: every record equally often (the default, and what every run before the forty-second session did).

``learnability``: records whose episodes sometimes lift and sometimes drop are drawn more often, in the spirit of
prioritized level replay (Jiang, Grefenstette & Rocktäschel 2021, "Prioritized Level Replay"), which replays the
levels with the largest learning signal.  Here the signal is the spread of a record's outcomes: PPO's advantage
on a start that always lifts, or never does, is ~0 (every return alike), so frames spent there teach nothing.

Per record i the env counts its finished training episodes n_i and successes s_i (lift above
``eval_success_height_m`` when the episode ends) and scores

    p_i = (s_i + a) / (n_i + 2a)              (posterior mean of the success rate under a Beta(a, a) prior)
    l_i = (4 p_i (1 - p_i)) ** k               (1 for an even record or one never tried; -> 0 for a sure one)
    P(i) = (1 - m) l_i / sum_j l_j + m / N    (a share m of the draws stays uniform, so no record is dropped)

with a = ``learnability_prior``, k = ``learnability_power`` and m = ``learnability_uniform_mix``.  The counts are
the sampling policy's own outcomes (exploration included).  Given a shared (N, 2) count array (the memory map of
one file, ``LiftEnvFactory.start_counts``), the envs of every collector worker count into and draw from the same
evidence (each count is read, incremented and written under an exclusive lock on the file, so two workers that
end episodes at the same moment both count), and a training resumed after a crash keeps them; otherwise each env
keeps its own.
"""

from __future__ import annotations

import os
from contextlib import AbstractContextManager, nullcontext
from typing import Callable, Optional

import numpy as np

try:
    import fcntl
except ImportError:  # Windows: no advisory locks; concurrent workers may then lose a count now and then
    fcntl = None


class FileLock:
    """An exclusive advisory lock (``fcntl.flock``) on one file, held inside ``with``; calling the instance returns
    itself, so it serves as the ``lock`` factory of :class:`LearnabilitySampler`.  Without ``fcntl`` (Windows) it
    locks nothing.  The file is opened on first use in each process (a forked child opens its own: a descriptor
    inherited across ``fork`` shares the parent's lock instead of excluding it), so a lock pickles as a path."""

    def __init__(self, path: str):
        self.path = str(path)
        self._fd: Optional[int] = None
        self._pid: Optional[int] = None

    def __call__(self) -> "FileLock":
        return self

    def __enter__(self) -> "FileLock":
        if fcntl is not None:
            if self._fd is None or self._pid != os.getpid():
                self._fd, self._pid = os.open(self.path, os.O_RDWR), os.getpid()
            fcntl.flock(self._fd, fcntl.LOCK_EX)
        return self

    def __exit__(self, *exc) -> None:
        if fcntl is not None and self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)

    def __getstate__(self) -> dict:
        return {"path": self.path, "_fd": None, "_pid": None}

    def __del__(self) -> None:
        if self._fd is not None and self._pid == os.getpid():
            os.close(self._fd)


class LearnabilitySampler:
    """Counts of finished episodes and successes per record, and draws a record index by learnability (module
    docstring).  Plain numpy; one per env."""

    def __init__(self, n_records: int, prior: float, power: float, uniform_mix: float,
                 counts: Optional[np.ndarray] = None,
                 lock: Optional[Callable[[], AbstractContextManager]] = None):
        """``counts``: an (n_records, 2) int64 array of (episodes, successes) per record to count into, e.g. a
        memory map shared by several processes; a fresh one when None.  ``lock``: a factory of the context manager
        that every update holds (for a shared ``counts``, an exclusive lock on its file); no lock when None."""
        if n_records < 1:
            raise ValueError("LearnabilitySampler needs at least one record")
        if prior <= 0.0 or power < 0.0 or not 0.0 <= uniform_mix <= 1.0:
            raise ValueError(f"LearnabilitySampler: prior {prior} must be > 0, power {power} >= 0 and "
                             f"uniform_mix {uniform_mix} in [0, 1]")
        if counts is None:
            counts = np.zeros((n_records, 2), dtype=np.int64)
        if counts.shape != (n_records, 2) or counts.dtype != np.int64:
            raise ValueError(f"LearnabilitySampler: counts of shape {counts.shape} and dtype {counts.dtype}, "
                             f"expected ({n_records}, 2) int64")
        self.prior, self.power, self.uniform_mix = float(prior), float(power), float(uniform_mix)
        self.counts = counts
        self._lock = lock or nullcontext
        self.episodes, self.successes = counts[:, 0], counts[:, 1]  # views: updates write into counts

    def success_estimates(self) -> np.ndarray:
        """(N,) posterior mean success rate of every record."""
        return (self.successes + self.prior) / (self.episodes + 2.0 * self.prior)

    def scores(self) -> np.ndarray:
        """(N,) learnability l_i in (0, 1]."""
        p = self.success_estimates()
        return (4.0 * p * (1.0 - p)) ** self.power

    def probabilities(self) -> np.ndarray:
        """(N,) the probability of drawing each record next."""
        scores = self.scores()
        n = len(scores)
        return (1.0 - self.uniform_mix) * scores / scores.sum() + self.uniform_mix / n

    def draw(self, rng: np.random.Generator) -> int:
        """A record index drawn with :meth:`probabilities`."""
        return int(rng.choice(len(self.episodes), p=self.probabilities()))

    def update(self, index: int, success: bool) -> None:
        """Count one finished training episode of record ``index``."""
        with self._lock():
            self.episodes[index] += 1
            self.successes[index] += int(bool(success))
