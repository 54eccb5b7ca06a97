"""How much one critic number can be trusted: critic accuracy over several seeds and both halves of the held-out
pairs of a simulated camera of ``simulated_camera_fidelity.py``, for saved profiles of that camera.

One critic (one seed, trained on the even held-out pairs, scored on the odd ones) either finds what tells a
simulation from its camera or does not; on the soft camera single critics range from 0.60 to 0.99 for one profile.
This trains ``--seeds`` critics on each half and scores each on the other half, with and without the clean source,
and prints mean ± standard deviation and every accuracy. Run from the repo root::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/simulated_camera_fidelity.py --pairs 96 --held-out 48 \\
        --cameras soft --curves none --save out/curves-none
    OMP_NUM_THREADS=2 .venv/bin/python experiments/simulated_camera_fidelity.py --pairs 96 --held-out 48 \\
        --cameras soft --save out/curves-channel
    OMP_NUM_THREADS=2 .venv/bin/python experiments/critic_seeds.py --camera soft \\
        --profile none=out/curves-none-soft.safetensors --profile channel=out/curves-channel-soft.safetensors
"""

from __future__ import annotations

import argparse
import json
import statistics

from simulated_camera_fidelity import pairs

from camdegrade import load_profile
from camdegrade._support.pixels import as_unit
from camdegrade.measures.critic import repeated_critic_test


def accuracies(cleans: list, reals: list, sims: list, seeds: int, image_only: bool) -> list[float]:
    """One accuracy per seed and half: trained on the even pairs and scored on the odd ones, or back."""
    names = [f"{index:04d}" for index in range(len(cleans))]  # in sorted order the pairs alternate even, odd
    result = repeated_critic_test((cleans, reals, sims), names, seeds, image_only=image_only)
    return [round(accuracy, 3) for accuracy in result.accuracies]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--camera", default="soft", choices=["soft", "dark"])
    parser.add_argument("--held-out", type=int, default=48)
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--profile", action="append", default=[], metavar="LABEL=PATH", required=True)
    args = parser.parse_args()
    held = pairs(args.camera, args.held_out, seed=11)  # the held-out pairs of simulated_camera_fidelity.py
    cleans = [as_unit(clean) for clean, _ in held]
    reals = [as_unit(captured) for _, captured in held]
    for entry in args.profile:
        label, _, path = entry.partition("=")
        profile = load_profile(path)
        sims = [(s.clamp(0, 1) * 255).round() / 255 for s in profile.simulate(cleans, seed=0, stream="heldout")]
        row = {"profile": label}
        for name, image_only in (("image_only", True), ("paired", False)):
            values = accuracies(cleans, reals, sims, args.seeds, image_only)
            row[name] = {
                "mean": round(statistics.mean(values), 3),
                "std": round(statistics.stdev(values), 3),
                "all": values,
            }
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
