"""Test helpers: ``vehicle.yaml`` files of vehicles the built-in ones are not, for blind trials."""

#: a 2.5 kg hexarotor with 10-inch propellers (0.127 m rotors), as this round's blind probe of ``uavturb gap`` flew
HEAVY_HEX = """name: heavy-hex-2.5kg
mass: 2.5
rotor_count: 6
arm_length: 0.30
rotor_angles_deg: [30, 90, 150, -150, -90, -30]
rotor_directions: [1, -1, 1, -1, 1, -1]
rotor_radius: 0.127
thrust_coefficient: 1.2e-05
moment_coefficient: 1.92e-07
inertia: [0.065, 0.07, 0.12]
max_rotor_speed: 1000.0
"""

#: a 2 kg quadrotor with 0.1 m rotors, as the same probe flew
HEAVY_QUAD = """name: heavy-quad-2kg
mass: 2.0
rotor_count: 4
arm_length: 0.25
rotor_angles_deg: [45, 135, -135, -45]
rotor_directions: [1, -1, 1, -1]
rotor_radius: 0.10
thrust_coefficient: 1.5e-05
moment_coefficient: 2.4e-07
inertia: [0.03, 0.03, 0.055]
max_rotor_speed: 1000.0
"""

#: a 3 kg hexarotor with 0.19 m rotors (six radii: 1.14 m: its indoor flights stay in the floor's reach), as a probe
#: of ``identify`` flew
BIG_HEX = """name: hex-3kg
mass: 3.0
rotor_count: 6
arm_length: 0.35
rotor_angles_deg: [30, 90, 150, -150, -90, -30]
rotor_directions: [1, -1, 1, -1, 1, -1]
rotor_radius: 0.19
thrust_coefficient: 3.0e-05
moment_coefficient: 6.0e-07
inertia: [0.08, 0.085, 0.15]
max_rotor_speed: 800.0
"""
