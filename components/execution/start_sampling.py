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
evidence (an increment lost to a race between two workers costs one episode's count), and a training resumed
after a crash keeps them; otherwise each env keeps its own.
"""

from __future__ import annotations

from typing import Optional

import numpy as np


class LearnabilitySampler:
    """Counts of finished episodes and successes per record, and draws a record index by learnability (module
    docstring).  Plain numpy; one per env."""

    def __init__(self, n_records: int, prior: float, power: float, uniform_mix: float,
                 counts: Optional[np.ndarray] = None):
        """``counts``: an (n_records, 2) int64 array of (episodes, successes) per record to count into, e.g. a
        memory map shared by several processes; a fresh one when None."""
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
        self.episodes[index] += 1
        self.successes[index] += int(bool(success))
