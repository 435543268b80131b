"""Sim-to-real gap finder: locate where simulation and real flights part, name the physics left
out (from the vocabulary of ``effects.md``), fit it, and put it back into the simulator."""
