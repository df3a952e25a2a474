"""Forty-fifth session, one-off screening runner (docs/experiments.md "What else moves Q1"): runs
``benchmarks.synthesis_experiment`` with the contact patches of the four fingers (assets/hand/contact_regions.yaml,
+-60 degrees about the palmar direction) widened to +-WIDE_DEG, so that the sides of the fingers are contact
candidates too and an object can be held between two fingers. The thumb's patches are left as they are. Usage: see
screen.sh beside this file."""
import importlib
import os
import sys

regions = importlib.import_module("components.hand.regions")
WIDE_DEG = float(os.environ["WIDE_DEG"])
released = regions._read_yaml


def widened(path, key):
    data = released(path, key)
    if key != "regions":
        return data
    return [dict(r, half_angle_deg=WIDE_DEG) if "half_angle_deg" in r and not r["name"].startswith("th") else r
            for r in data]


regions._read_yaml = widened
if __name__ == "__main__":
    from benchmarks.synthesis_experiment import main

    sys.exit(main())
