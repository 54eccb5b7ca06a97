"""Which change closes the gap: the kinds of change (:mod:`.changes`) and where a candidate goes in the chain
(:mod:`.placement`), the search that makes and measures them round by round (:mod:`.search`, :mod:`.strength`,
what a change reads of a round in :mod:`.round_view`), the cause rule (:mod:`.signature`) and the attribution
that drives them (:mod:`.attribute`)."""

__all__: list[str] = []
