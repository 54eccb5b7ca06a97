"""Cache keys over a module's tensors."""

from __future__ import annotations

import torch

from camdegrade import load_profile
from camdegrade._support.fingerprint import module_tensors, tensors_fingerprint


def test_module_tensors_are_the_parameters_and_buffers():
    profile = load_profile("city100-iphonex")
    walked = {id(t) for t in module_tensors(profile)}
    assert walked == {id(t) for t in [*profile.parameters(), *profile.buffers()]}
    assert len(walked) > 8  # the network's 8 parameters and the effect stages' buffers


def test_the_fingerprint_changes_with_an_in_place_edit_or_a_swap():
    profile = load_profile("city100-iphonex")
    before = tensors_fingerprint(module_tensors(profile))
    assert tensors_fingerprint(module_tensors(profile)) == before
    with torch.no_grad():
        profile.network.decode2.bias.add_(0.0)
    edited = tensors_fingerprint(module_tensors(profile))
    assert edited != before
    profile.effects[1].sigma_x = profile.effects[1].sigma_x.clone()  # the blur (after the jitter)
    assert tensors_fingerprint(module_tensors(profile)) != edited
