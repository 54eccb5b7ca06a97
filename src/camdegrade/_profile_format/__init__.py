"""The profile file format, read and checked without torch (``camdegrade list``/``info`` answer in a fraction of a
second; :func:`camdegrade.load_profile` runs the same check before it builds anything).

- :mod:`.header`: the safetensors header and the metadata JSON of a profile file, written and read.
- :mod:`.check`: the one check of a file's metadata and tensors that ``info`` and ``load_profile`` share.
- :mod:`.network_entry`: the ``network`` entry (its class, constructor arguments and tensors), read without torch.
- :mod:`.effect_facts`: each built-in effect's file facts (stage, config keys, tensor shapes, ranges), held to the
  effect classes by ``tests/test_profile_validation.py``.
- :mod:`.summary`: a profile for people (``camdegrade info``, ``make demo``, the end of a fit).
"""
