"""``uavturb generate flight``: :mod:`~uavturb.sim.flights.plans` (flight plans in a room),
:mod:`~uavturb.sim.flights.simulate` (the simulated recording), :mod:`~uavturb.sim.flights.sensors`,
:mod:`~uavturb.sim.flights.conditions` (real recordings' troubles, with their truth; their schema, from
which the command's options are generated, in :mod:`~uavturb.sim.flights.condition_schema`),
:mod:`~uavturb.sim.flights.stream_troubles`, :mod:`~uavturb.sim.flights.ground_contact` and
:mod:`~uavturb.sim.flights.euroc_standin`."""

from __future__ import annotations
