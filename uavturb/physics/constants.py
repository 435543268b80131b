"""Physical constants shared by the physics and everything above it."""

from __future__ import annotations

GRAVITY = 9.81  # m/s^2, |g|; gravity in W is (0, 0, -GRAVITY) (recordings.md)
AIR_DENSITY = 1.225  # kg/m^3, ISA sea level
