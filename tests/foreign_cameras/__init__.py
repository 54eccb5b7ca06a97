"""Foreign cameras: simulated cameras written without camdegrade, to check its fit and diagnosis on chains it did not
build (issue 42, item 1).

Every camera is a documented physical chain of plain numpy / scipy / PIL steps (``cameras.py``): resamplers from PIL,
a Bayer colour filter array with two demosaicers of our own (``demosaic.py``), 8-bit quantization between stages,
tone through a look-up table applied to already-quantized values, lens blur in linear light and in gamma, JPEG from
PIL at sensor resolution and at the end. Nothing here imports camdegrade or torch (``tests/test_foreign_cameras.py``
parses the imports), so a fit or a diagnosis that matches one of these cameras has earned the match.

The package sits under ``tests/`` because it is test support, not part of the installed library (``src/`` is what
ships): the tests import it as ``foreign_cameras`` (``tests/`` is on pytest's path, as for ``effects_images``), and
the bench scripts (``bench/bench_foreign_*.py``) put ``tests/`` on ``sys.path`` the same way.

These cameras are for checking only: never tune a hyper-parameter of camdegrade on them.

Example::

    from foreign_cameras import CAMERAS, scenes
    clean = scenes(4, 128, seed=0)
    captured = [CAMERAS["webcam"]()(image, seed=(7, index)) for index, image in enumerate(clean)]
"""

from foreign_cameras.cameras import CAMERAS, Camera, camera
from foreign_cameras.scenarios import BASES, CHECK_BASES, SCENARIOS, Scenario
from foreign_cameras.scenes import scenes

__all__ = ["BASES", "CAMERAS", "CHECK_BASES", "SCENARIOS", "Camera", "Scenario", "camera", "scenes"]
