"""Collection rules for the whole tree (the doctests under src/ included)."""

import importlib.util
import os

# albumentations looks for a newer release online when imported; tests never reach the network.
os.environ.setdefault("NO_ALBUMENTATIONS_UPDATE", "1")

# The albumentations adapter's module imports albumentations (an optional extra): without it, skip its doctests
# rather than fail the collection.
collect_ignore = [] if importlib.util.find_spec("albumentations") else ["src/camdegrade/integrations/albumentations.py"]
