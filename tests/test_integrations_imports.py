"""The integrations stay optional: importing camdegrade (or its integrations package) imports none of their stacks."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import camdegrade

OPTIONAL_STACKS = ("albumentations", "albucore", "cv2", "datasets", "pyarrow", "lightning", "pytorch_lightning")


@pytest.mark.slow
def test_importing_camdegrade_imports_no_optional_stack():
    code = (
        "import sys\n"
        "import camdegrade, camdegrade.data, camdegrade.integrations\n"
        "print(camdegrade.__file__)\n"
        f"print(sorted(name for name in {OPTIONAL_STACKS!r} if name in sys.modules))\n"
    )
    # The child must import this checkout's camdegrade, whatever is installed in the environment.
    source_root = str(Path(camdegrade.__file__).resolve().parents[1])
    path = os.pathsep.join(filter(None, [source_root, os.environ.get("PYTHONPATH")]))
    env = {**os.environ, "PYTHONPATH": path, "OMP_NUM_THREADS": "1"}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    imported_from, loaded = result.stdout.strip().splitlines()
    assert Path(imported_from).resolve() == Path(camdegrade.__file__).resolve()
    assert loaded == "[]", result.stderr
