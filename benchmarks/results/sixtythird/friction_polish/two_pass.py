"""Sixty-third session, one-off screening runner (docs/experiments.md "A second refinement under less friction"):
runs ``benchmarks.synthesis_experiment`` with ``components.synthesis.synthesize`` replaced by a two-pass variant.
Pass 1 is the profile's chain (approach, MALA, refinement) at its ``fc_friction``; pass 2 refines the result again
(the profile's refinement, contacts reassigned as there, POLISH_STEPS Adam steps) with E_fc's friction set to
POLISH_FRICTION, and the filter and every stored term are those of pass 2's friction.  The question: does a chain
that has found force closure under mu 0.5 reach it under mu 0.2 more often than a chain run at 0.2 from the start
(15 % accepted, "Less friction in E_fc, under the current profile")?  Usage: screen.sh of
../../fortyfifth/q1_screens with RUNNER=benchmarks/results/sixtythird/friction_polish/two_pass.py."""
import dataclasses
import importlib
import json
import os
import sys
import time

syn = importlib.import_module("components.synthesis.synthesize")
package = importlib.import_module("components.synthesis")
FRICTION = float(os.environ.get("POLISH_FRICTION", "0.2"))
STEPS = int(os.environ.get("POLISH_STEPS", "400"))


def two_pass(hand, library, scene, cfg, generator, progress=None):
    start = time.perf_counter()
    objects = syn.SceneObjects(library, scene, hand.device, hand.dtype)
    problem = syn.GraspProblem.build(hand, objects, cfg)
    x, contacts = syn.initial_poses(problem, generator)
    if cfg.approach_steps > 0:
        x, contacts, _ = syn.approach(problem, x, contacts, progress)
    state, mala_stats = syn.run_mala(problem, x, contacts, generator, progress)
    x, contacts, _ = syn.refine(problem, state.x, state.contacts, progress)
    pass1_terms = syn.energy_and_grad(problem, x, contacts)[2]
    pass1_terms.pop(syn.CONTACT_INDICES), pass1_terms.pop(syn.CANDIDATE_POINTS)
    pass1_accepted, _ = syn.filter_grasps(pass1_terms, cfg)
    cfg2 = cfg.model_copy(update={"fc_friction": FRICTION, "refine_steps": STEPS})
    problem2 = dataclasses.replace(problem, cfg=cfg2)
    x, contacts, _ = syn.refine(problem2, x, contacts, progress)
    energy, _, terms = syn.energy_and_grad(problem2, x, contacts)
    contacts = terms.pop(syn.CONTACT_INDICES)
    contact_points = syn.gather_contacts(terms.pop(syn.CANDIDATE_POINTS), contacts)
    accepted, reasons = syn.filter_grasps(terms, cfg2)
    p, R, q = syn.unpack(x)
    q = problem.effective_joints(q)
    stats = {**mala_stats, "seconds": time.perf_counter() - start, "accept_rate": float(accepted.float().mean()),
             "pass1_accepted": int(pass1_accepted.sum()), "pass1_and_pass2_accepted": int((pass1_accepted & accepted).sum()),
             "lineages_accepted": int(state.ancestor[accepted].unique().numel())}
    print("two_pass " + json.dumps({"objects": list(objects.names), "friction": FRICTION, "steps": STEPS,
                                    **{k: stats[k] for k in ("pass1_accepted", "pass1_and_pass2_accepted")},
                                    "accepted": int(accepted.sum()), "batch": int(accepted.numel())}),
          file=sys.stderr, flush=True)
    return syn.SynthesisResult(scene=scene, object_names=list(objects.names), p=p, R=R, q=q, contacts=contacts,
                               contact_regions=hand.contact_region_of[contacts], contact_points=contact_points,
                               energy=energy, terms=terms, accepted=accepted, reasons=reasons, stats=stats,
                               lineage=state.ancestor)


syn.synthesize = two_pass
package.synthesize = two_pass
if __name__ == "__main__":
    from benchmarks.synthesis_experiment import main

    sys.exit(main())
