"""The detail response fitted once more, through the noise refitted after it.

The response and the noise both set the top of the simulated spectrum: the response is fitted through the noise of
its time, then the noise is fitted again through the response (it shapes the noise before it, as the camera's
does), and that refit leaves the response's match behind. On City100's unpaired split (captures 036–055, clean
001–035) the noise went 0.598 → 0.549 levels at mid-grey, and the 0.38–0.5 cycles/pixel band the response had
matched fell 0.35 log2 (the response's record said a mismatch of 0.001, the profile's own check 0.022); on the 16
held-out pairs the 0.35–0.5 band read −0.33 log2, −0.07 with the response refitted (docs/results.md, "The top
bands"). Fitted again through the final noise, the response leaves the flat noise where it was (1.26 → 1.26 on the
held-out pairs): one refit, no loop."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from torch import Tensor

from camdegrade.effects import FrequencyResponse
from camdegrade.fitting.steps.base import Verdict
from camdegrade.fitting.unpaired.bench import UnpairedFit
from camdegrade.fitting.unpaired.steps.spectrum import (
    DetailResponseMatch,
    fit_band_gains,
    mean_spectrum,
    radial_response,
)

__all__ = ["DetailResponseRefit"]


@dataclass(frozen=True)
class ResponseRefit:
    """The kept response's mismatch through today's chain, and the gains fitted afresh through it."""

    before: float
    gains: Tensor
    rounds: list[float]


@dataclass(frozen=True)
class DetailResponseRefit(DetailResponseMatch):
    """Where a detail response is kept, its band gains fitted again (:func:`fit_band_gains`, on the whole sets)
    through the chain as it stands, kept unless they take the simulation's step width farther from the captures'
    (the response's own rule); the record is the response's, its gains and mismatch those of the refit, with
    ``refit``: the old response's mismatch through today's chain and the new one's."""

    def applies(self, fit: UnpairedFit) -> bool:
        return fit.stages.get(FrequencyResponse.name) is not None

    def propose(self, fit: UnpairedFit) -> ResponseRefit | Verdict:
        real = fit.sets.real_spectra.mean(0)
        crops = fit.sets.spectrum_crops
        before = float((mean_spectrum(fit.simulate(fit.chain(), crops, "unpaired-response")) - real).pow(2).mean())
        simulate = self._simulate(fit)
        gains, rounds = fit_band_gains(real, lambda g: simulate(g, slice(None)))
        return ResponseRefit(before, gains, rounds)

    def judge(self, fit: UnpairedFit, proposal: ResponseRefit) -> dict[str, Any]:
        notes = dict(fit.records.get(self.name, {}))
        response = radial_response(proposal.gains)
        after = float((self._simulate(fit)(proposal.gains, slice(None)) - fit.sets.real_spectra.mean(0)).pow(2).mean())
        checked: dict = {}
        refused = self._sharpens_away(fit, response, checked)
        notes["refit"] = {
            "before": round(proposal.before, 4),
            "after": round(after, 4),
            "kept": not refused,
            **({"edges": checked["edges"]} if "edges" in checked else {}),
        }
        if not refused:
            fit.keep(response)
            notes["band_gains"] = [round(float(value), 3) for value in proposal.gains.exp2()]
            notes["rounds"] = [round(value, 4) for value in proposal.rounds]
            notes["mismatch"] = round(after, 4)
        fit.say(f"detail response through the refitted noise: {notes['refit']}")
        return notes
