"""How much the critics at the end of a fit move with more critic seeds, on that fit's own validation pairs.

``fit_profile`` records 4 critics per mode (2 seeds, each trained on one half of the validation scenes and scored
on the other, and back; :func:`~camdegrade.measures.critic.repeated_critic_test`). This re-runs them on the fit's
validation scenes (``fitted['validation_scenes']``, the profile sampled as the fit samples it: seed 0, stream
``quality``, rounded to 8 bits) with ``--seeds`` seeds, paired and image-only, and prints every critic's
accuracy. With ``--seeds 2`` it repeats the fit's own numbers. Run from the repo root::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/fit_critic_seeds.py PROFILE PAIRS [--seeds 4]
"""

from __future__ import annotations

import argparse

from camdegrade import load_profile
from camdegrade.fitting.steps.noise_evidence import as_stored
from camdegrade.measures.critic import repeated_critic_test
from camdegrade.pairs.pairset import PairSet


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("profile", help="a profile written by camdegrade fit")
    parser.add_argument("pairs", help="the pairs it was fitted on (folder or CSV manifest)")
    parser.add_argument("--seeds", type=int, default=4)
    args = parser.parse_args()
    profile = load_profile(args.profile)
    scenes = set(profile.fitted["validation_scenes"])
    pairs = PairSet.load(args.pairs)
    validation = pairs.subset([index for index, scene in enumerate(pairs.scenes) if scene in scenes])
    cleans, captures = validation.cleans(), validation.captured()
    sampled = as_stored(profile.simulate(cleans, 0, stream="quality"), eight_bit=True)
    for image_only in (False, True):
        result = repeated_critic_test((cleans, captures, sampled), validation.scenes, args.seeds, image_only=image_only)
        label = "image-only" if image_only else "paired"
        each = " ".join(f"{accuracy:.3f}" for accuracy in result.accuracies)
        print(f"{label:10s} {result.describe()} ({result.seconds:.1f} s); each: {each}", flush=True)


if __name__ == "__main__":
    main()
