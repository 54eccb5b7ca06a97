"""Collection rules for the whole tree (the doctests under src/ included)."""

import importlib.util

# The albumentations adapter's module imports albumentations (an optional extra): without it, skip its doctests
# rather than fail the collection.
collect_ignore = [] if importlib.util.find_spec("albumentations") else ["src/camdegrade/integrations/albumentations.py"]
