"""Sentences a flight engineer would write about each named effect."""

from __future__ import annotations

import numpy as np

from uavturb.gap.design import GapData
from uavturb.physics.constants import GRAVITY


def explanation(name: str, params: dict[str, float], data: GapData, k_T: float) -> str:
    """One or two sentences: what the effect is, how large it is on these flights, what to do."""
    hover_w = float(np.sqrt(data.mass * GRAVITY / (k_T * data.rotor_speeds.shape[1])))
    wsum_hover = hover_w * data.rotor_speeds.shape[1]
    speed = float(np.percentile(np.linalg.norm(data.v[:, :2], axis=1), 90))
    if name == "rotor_drag":
        per = params["k_d"] * wsum_hover
        return (f"Horizontal drag proportional to rotor speed and body-horizontal airspeed is missing: about "
                f"{per:.3g} N per m/s at hover ({per * speed:.2g} N at this flight's {speed:.1f} m/s). "
                f"Add RotorS-style rotor drag with k_d = {params['k_d']:.3g} N s^2/m.")
    if name == "body_drag":
        return (f"The airframe's quadratic drag is missing: {params['c_d'] * speed**2:.2g} N at {speed:.1f} m/s, "
                f"growing with the square of speed. Add body drag with c_d = {params['c_d']:.3g} kg/m.")
    if name == "wind":
        mag = float(np.hypot(params["f_x"], params["f_y"]))
        heading = float(np.degrees(np.arctan2(params["f_y"], params["f_x"])))
        return (f"A steady horizontal push of {mag:.2g} N towards {heading:.0f} deg (world frame) that stays fixed in "
                f"the world while the heading changes, so it is not an accelerometer bias: a draught or steady wind.")
    if name == "ground_effect":
        d = 2 * data.rotor_radius
        rho = params["mu"] * (data.rotor_radius / (4 * d)) ** 2
        return (f"Extra lift near the surface below follows the Cheeseman-Bennett law with mu = {params['mu']:.3g} "
                f"(+{100 * rho / (1 - rho):.1f} % thrust at two rotor radii). Switch ground_effect on in the simulator.")
    if name == "ceiling_effect":
        return (f"Suction towards the surface above follows the ceiling law with kappa = {params['kappa']:.3g}; "
                f"it matters within a few rotor radii of the ceiling or of furniture overhead.")
    if name == "battery_sag":
        return (f"Thrust per rotor speed falls as the flight goes on, by {100 * params['s'] * 60:.2g} % per minute "
                f"(s = {params['s']:.3g} 1/s): battery voltage sag. Model it, or feed the controller the voltage.")
    if name == "motor_lag":
        return (f"The rotors follow their commands with a first-order lag of {1000 * params['tau']:.0f} ms: the "
                f"recorded speeds are commands. Add a motor time constant to the simulator and controller.")
    return f"{name} with {params}."
