"""The curriculum that adapts a specialist to imprecise pre-grasps (paper §"Learning from Imprecise Poses").

"The training regimen is divided into three phases: the first phase focuses on synthetic pre-grasp poses; the second
phase introduces these imprecise poses, encompassing both synthetic and generated instances where objects have been
displaced; the final phase predominantly incorporates generated data with moved objects."

Three pools of starts per specialist bin:

* ``synthetic``: the bin's synthesised pre-grasps (what the specialist trained on);
* ``reached``: the same pre-grasps after the planned reach from an open hand (the reach stage's end-of-reach
  states: the objects possibly pushed);
* ``generated``: the trained generator's pre-grasps for new placements of the bin's objects, after their reach.

:func:`phase_starts` gives each phase's starts as one list that a uniform draw samples in the phase's proportions
(each pool repeated in turn to its share): phase 1 synthetic only; phase 2 ``phase2_imprecise_share`` from the
imprecise pools (reached and generated alike), the rest synthetic; phase 3 ``phase3_generated_share`` generated, the
rest from the other two.  A pool that is empty hands its share to the others.  ``schedule: mixed`` (the paper's
"w/o Curr") draws every phase from all the starts alike.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal, TypeVar

from pydantic import Field

from components.config_base import Section

T = TypeVar("T")

PHASES = 3


class CurriculumConfig(Section):
    """The three phases of adaptation and the generated pre-grasps of phases 2 and 3."""

    phase_iterations: list[int] = Field(
        default_factory=lambda: [10, 10, 10], min_length=PHASES, max_length=PHASES,
        description="PPO iterations of phases 1, 2 and 3, continued from the specialist's checkpoint (its PPO settings).")
    phase2_imprecise_share: float = Field(
        0.5, ge=0.0, le=1.0, description="Phase 2: share of the episodes that start from imprecise pre-grasps (reached "
        "synthetic and reached generated alike); the rest start from the synthetic ones.")
    phase3_generated_share: float = Field(
        0.8, ge=0.0, le=1.0, description="Phase 3: share of the episodes that start from reached generated pre-grasps "
        "(the paper's 'predominantly'); the rest from the synthetic and reached synthetic ones.")
    schedule: Literal["phased", "mixed"] = Field(
        "phased",
        description="phased: the paper's three phases (module docstring).  mixed: every phase draws from all the starts "
        "alike (synthetic, reached and generated together), the same iterations: adaptation without the structured "
        "curriculum, the paper's 'w/o Curr' (multigrasp evaluate curriculum trains it).")
    filter_generated: bool = Field(
        False,
        description="Keep only the generated pre-grasps that the paper's protocol filter keeps (generator.eval_filter: "
        "penetration and contact ratio).  False (default): every generated pre-grasp of the bin's sector is reached "
        "and used -- the paper's imprecise poses are the generator's own, and the filter is its evaluation's protocol; "
        "on the mini generator (600 steps) the filter kept 0 of 32 (fifty-eighth session).")
    generated_scenes: int = Field(2, ge=1, description="New placements of the bin's objects sampled (and settled) per bin for its generated pre-grasps.")
    generated_per_scene: int = Field(8, ge=1, description="Generated pre-grasps per placement (before the protocol filter and the bin's sector).")
    seed: int = Field(0, ge=0, description="Seed of the placements and the generator's noise.")


def repeated_to(items: Sequence[T], n: int) -> list[T]:
    """``items`` repeated in turn to ``n`` entries (empty when there are none)."""
    return [items[i % len(items)] for i in range(n)] if items and n > 0 else []


def mix(pools: Sequence[tuple[Sequence[T], float]]) -> list[T]:
    """One list whose uniform draw picks from each (pool, share) with that share (to rounding), each pool's items in
    turn; the shares of empty pools go to the others in proportion.  Every non-empty pool with a share keeps each of
    its items at least once."""
    live = [(list(items), share) for items, share in pools if items and share > 0]
    if not live:
        return []
    total = sum(share for _, share in live)
    n = max(int(round(len(items) / (share / total))) for items, share in live)
    return [x for items, share in live for x in repeated_to(items, max(len(items), int(round(n * share / total))))]


def phase_starts(phase: int, synthetic: Sequence[T], reached: Sequence[T], generated: Sequence[T],
                 cfg: CurriculumConfig) -> list[T]:
    """The starts of phase ``phase`` (1, 2 or 3; module docstring); with ``schedule`` 'mixed' every phase's are all
    the starts."""
    if phase in range(1, PHASES + 1) and cfg.schedule == "mixed":
        return [*synthetic, *reached, *generated]
    if phase == 1:
        return list(synthetic)
    if phase == 2:
        imprecise = list(reached) + list(generated)
        return mix([(synthetic, 1.0 - cfg.phase2_imprecise_share), (imprecise, cfg.phase2_imprecise_share)])
    if phase == 3:
        return mix([(list(synthetic) + list(reached), 1.0 - cfg.phase3_generated_share),
                    (generated, cfg.phase3_generated_share)])
    raise ValueError(f"phase {phase}: the curriculum has phases 1 to {PHASES}")
