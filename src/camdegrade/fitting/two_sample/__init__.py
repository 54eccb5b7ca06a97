"""What no named stage makes, learned: a :class:`~camdegrade.effects.LearnedTexture` stage trained after a profile's
named stages by a two-sample objective against the camera's own photos (:func:`fit_two_sample`: the trainer,
:mod:`~camdegrade.fitting.two_sample.critic` its patch critic, :mod:`~camdegrade.fitting.two_sample.state` its
resumable state), and the gate that keeps it only where held-out halves say so
(:mod:`~camdegrade.fitting.two_sample.gate`: :func:`~camdegrade.fitting.two_sample.gate.fit_learned_stage` and the
unpaired fit's step; not imported here, it builds on the unpaired fit, which imports it)."""

from camdegrade.fitting.two_sample.train import TwoSampleOptions, fit_two_sample

__all__ = ["TwoSampleOptions", "fit_two_sample"]
