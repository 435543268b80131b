"""uavturb: learning UAV-created turbulence from scene structure seen by onboard cameras.

Reimplements Possamaï et al., "Learning to estimate UAV created turbulence from scene
structure observed by onboard cameras", and extends it with a simulator and a
sim-to-real gap finder.
"""

__version__ = "0.1.0"
