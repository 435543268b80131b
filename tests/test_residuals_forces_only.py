"""``uavturb residuals`` asks for forces: a flight that cannot determine the inertia still gives them
(torques left out as nan with one line saying why), instead of failing."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from uavturb.commands.identify import residuals_to_file
from uavturb.io.writer import write_recording
from uavturb.physics.effects import parse_effects
from uavturb.physics.vehicle import HEXAROTOR
from uavturb.sim.flights.simulate import simulate_flight
from uavturb.sim.core.signals import Constant, Reference, Sines


def test_hover_without_inertia_gives_forces_and_nan_torques(tmp_path, capsys):
    bob = Reference(Constant(0.0), Constant(0.0), Sines((1.5, 0.1), (0.0, 2.0), (1.5708, 0.0)), Constant(0.0), 8.0,
                    "vertical bobbing")  # all rotors change together: no torque to identify the inertia with
    rec, truth = simulate_flight(HEXAROTOR, bob, effects=parse_effects("wind:f_x=0.4"), seed=3)
    rec = dataclasses.replace(rec, vehicle=HEXAROTOR.with_params(inertia=None, moment_coefficient=None))
    write_recording(rec, tmp_path / "hover")
    res, path = residuals_to_file(tmp_path / "hover", tmp_path / "r.csv")
    table = pd.read_csv(path)
    assert np.all(np.isnan(table["tau_Bx [N m]"])) and np.all(np.isfinite(table["F_x [N]"]))
    settled = table["t [s]"] > 2.0
    assert abs(table.loc[settled, "F_x [N]"].median() - 0.4) < 0.05  # the wind's push, from the forces alone
    assert "torques left out (nan)" in capsys.readouterr().err


def test_rotor_columns_out_of_order_are_said_where_their_torques_are_written(tmp_path, capsys):
    weave = Reference(Sines((0.4,), (3.0,), (0.0,)), Sines((0.4,), (3.7,), (1.0,)), Constant(1.5), Constant(0.0), 10.0,
                      "weave")  # rolls and pitches (accelerations to 5 m/s^2): torques the accelerations follow
    rec, _ = simulate_flight(HEXAROTOR, weave, seed=4)
    turned = dataclasses.replace(rec.rotors, speeds=rec.rotors.speeds[:, [1, 2, 3, 4, 5, 0]])
    write_recording(dataclasses.replace(rec, rotors=turned), tmp_path / "turned")
    residuals_to_file(tmp_path / "turned", tmp_path / "r.csv")
    err = capsys.readouterr().err
    # a hexarotor's six rotor speeds move with four commands: the flight says the order is not vehicle.yaml's, and
    # finds orders it cannot tell apart (mirror images of the frame) among the 720
    assert ("uavturb residuals: the rotor columns are in another order than vehicle.yaml's angles, which the flight "
            "does not tell:") in err and "check which column holds which rotor" in err
    write_recording(rec, tmp_path / "as_flown")
    residuals_to_file(tmp_path / "as_flown", tmp_path / "r2.csv")
    assert "another order" not in capsys.readouterr().err
