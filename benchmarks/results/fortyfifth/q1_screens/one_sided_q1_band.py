"""Forty-fifth session, one-off screening runner (docs/experiments.md "What else moves Q1"): runs
``benchmarks.synthesis_experiment`` with E_q1's contact band made one-sided. The released surrogate
(``components.synthesis.energy.q1_surrogate``) weighs a hand sample at signed distance d by relu(1 - |d| / band) on
both sides of the surface; here a sample inside the object fades out within Q1_INSIDE_BAND_M instead, so pressing in
earns E_q1 (almost) nothing. Done by handing the surrogate an effective distance for the weight and points moved so
that its surface projection is unchanged. Usage: see screen.sh beside this file."""
import importlib
import os
import sys

import torch

energy = importlib.import_module("components.synthesis.energy")
INSIDE_BAND_M = float(os.environ["Q1_INSIDE_BAND_M"])
released = energy.q1_surrogate


def one_sided(points, distances, normals, centre, radius, directions, band, *args, **kwargs):
    effective = torch.where(distances >= 0, distances, distances * (band / INSIDE_BAND_M))
    moved = points + (effective - distances).unsqueeze(-1) * normals  # moved - effective n = points - distances n
    return released(moved, effective, normals, centre, radius, directions, band, *args, **kwargs)


energy.q1_surrogate = one_sided
if __name__ == "__main__":
    from benchmarks.synthesis_experiment import main

    sys.exit(main())
