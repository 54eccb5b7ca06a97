"""Leaf helpers every layer may use (each imports nothing of camdegrade but this folder): argument checks, atomic
files, 8-bit pixels, derived seeds, terminal text, the recipes' fields, tensor fingerprints, large normal fields."""

__all__: list[str] = []
