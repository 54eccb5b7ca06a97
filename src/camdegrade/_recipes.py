"""The fitting recipes' values, in one place and without torch (the CLI's help text reads them)."""

from __future__ import annotations

from typing import Any

#: camdegrade's default recipe: many small steps on small windows (batches of 8 windows of 64², 32 per pair and
#: epoch: the pixels of 8 windows of 128², in four times the steps), Adam on a cosine schedule over 10 epochs,
#: stopping early once the validation PSNR stops rising (``patience`` epochs without 0.01 dB of progress). Chosen on
#: City100 and a simulated camera (``examples/recipe_comparison.py``, docs/fitting.md).
FAST: dict[str, Any] = {
    "epochs": 10,
    "crop": 64,
    "batch_size": 8,
    "lr": 0.003,
    "lr_halving_epochs": 30,
    "crops_per_pair": 32,
    "seed": 0,
    "schedule": "cosine",
    "patience": 4,
    "precision": "auto",
    "width": 64,
}
#: The paper's schedule (Hegde et al.): 100 epochs, Adam at lr 0.01 halved every 30 epochs, batch 32, no early stop;
#: 8 windows of 128² per pair and epoch.
PAPER: dict[str, Any] = {
    **FAST,
    "epochs": 100,
    "crop": 128,
    "batch_size": 32,
    "lr": 0.01,
    "crops_per_pair": 8,
    "schedule": "step",
    "patience": 0,
}
RECIPES: dict[str, dict[str, Any]] = {"fast": FAST, "paper": PAPER}


def recipe_default(key: str) -> str:
    """``key``'s value in each recipe, for help text: ``"15; paper: 100"``, or one value where they agree."""
    fast, paper = FAST[key], PAPER[key]
    return f"{fast}" if fast == paper else f"{fast}; paper: {paper}"
