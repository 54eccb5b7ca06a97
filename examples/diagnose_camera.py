"""Diagnose a profile: where its simulations still differ from your camera's captures, and what to change.

    python examples/diagnose_camera.py PROFILE PAIRS --html report.html -o fixed.safetensors
    python examples/diagnose_camera.py --demo --html out/diagnose-camera/report.html

PAIRS are (clean, captured) pairs of your camera that the profile was NOT fitted on, laid out as for
``camdegrade fit`` (docs/diagnosis.md). ``--demo`` needs neither: a virtual camera (lens blur σ 1.2 px and sensor
noise) captures generated photos, and the profile to diagnose has the camera's noise but not its blur. It prints
the verdict (what differs, which change closes how much of the gap, what a critic can still tell apart), writes
the HTML report, and the profile with the accepted changes.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from camdegrade import CameraProfile, VirtualCamera, diagnose
from camdegrade.effects import Blur, Noise
from camdegrade.synthetic import dead_leaves_images


def demo_camera_and_profile(count: int, size: int, seed: int) -> tuple[CameraProfile, list]:
    """A profile without the camera's blur, and ``count`` (clean, captured) pairs of that camera."""
    noise = {"a": 0.002, "b": 2e-5}
    camera = VirtualCamera([Blur(sigma_x=1.2), Noise(**noise)])
    generator = torch.Generator().manual_seed(seed)
    cleans = dead_leaves_images(count, size, seed=seed)
    pairs = [(clean, camera(clean, generator=generator)) for clean in cleans]
    return CameraProfile(None, [Noise(**noise)], name="no-blur"), pairs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("profile", nargs="?", help="a built-in profile name or a .safetensors path (or --demo)")
    parser.add_argument("pairs", nargs="?", type=Path, help="pairs the profile was not fitted on")
    parser.add_argument("--demo", action="store_true", help="diagnose a virtual camera's pairs instead")
    parser.add_argument("--html", type=Path, help="write the HTML report here")
    parser.add_argument("-o", "--output", type=Path, help="write the profile with the accepted changes here")
    parser.add_argument("--no-critic", action="store_true", help="skip the learned critic (faster)")
    parser.add_argument("--demo-pairs", type=int, default=24, help="how many pairs --demo makes (default 24)")
    parser.add_argument("--demo-size", type=int, default=128, help="their side in pixels (default 128)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    given = args.profile is not None and args.pairs is not None
    if args.demo == given or (args.demo and args.profile is not None):
        parser.error("give PROFILE and PAIRS, or --demo")

    if args.demo:
        profile, pairs = demo_camera_and_profile(args.demo_pairs, args.demo_size, args.seed)
    else:
        profile, pairs = args.profile, args.pairs
    report = diagnose(profile, pairs, seed=args.seed, critic=not args.no_critic, log=print)  # ends with the verdict
    print(f"accepted: {', '.join(report.accepted) or 'nothing'}")
    if args.html is not None:
        report.write_html(args.html)
        print(f"wrote {args.html}")
    if args.output is not None and report.accepted:
        report.profile.save(args.output)
        print(f"wrote {args.output} (the profile with the accepted changes)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
