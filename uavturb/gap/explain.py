"""Sentences a flight engineer would write about each named effect, from facts measured on the
recordings (:func:`uavturb.gap.decide.flight_facts`): the wording lives with each effect in the
registry (:data:`uavturb.physics.effects.EFFECTS`), and a claim such as "the heading changed" is
written only where it did."""

from __future__ import annotations

from uavturb.physics.effects import EFFECTS, FlightFacts


def explanation(name: str, params: dict[str, float], facts: FlightFacts) -> str:
    """One or two sentences: what the effect is, how large it is on these flights, what to do."""
    return EFFECTS[name].explain(params, facts)
