"""Stand-in EuRoC flights: ``uavturb generate flight --kind euroc_room`` (the real EuRoC data is not here).

What makes a simulated flight look like EuRoC's Vicon-room sequences (V1_01_easy, V1_02_medium),
the flights of the paper's Table 2:

- **the flight** (:func:`uavturb.sim.flights.plans.euroc_room`): take-off from the floor, flight
  0.5-2 m over the floor and the furniture of :data:`uavturb.sim.flights.plans.EUROC_ROOM`, landing on
  the floor; about 2-3 s below 0.3 m at each end, 1 s at rest (the dynamics have no contact: "at
  rest" is a hover at the landed height);
- **the vehicle's legs**: landed, the body origin stands :func:`landed_height` (0.16 m) over the
  floor, so that cam0, 0.13 m under it, stays 3 cm over the floor (ours: the geometry of the
  mount, not a measurement of the Firefly);
- **the sensor frame**: ground truth and IMU in EuRoC's S (the VI-sensor's IMU), placed in B by
  ``vehicle.yaml``'s ``T_BS``: the Firefly's (``uavturb/vehicles/firefly.yaml``) unless the vehicle
  has its own (:func:`with_vi_sensor`);
- **cam0**: ``mav0/cam0/sensor.yaml`` of EuRoC's cam0 (:data:`uavturb.scene.camera.EUROC_CAM0`:
  intrinsics, 752 x 480, 20 Hz, radial-tangential distortion, ``T_BS`` relative to S), no images:
  ``uavturb evaluate`` projects the recording's point cloud through it at its 20 Hz, as the paper
  does on EuRoC (:func:`with_cam0`);
- **the point cloud**: the room's mesh sampled every 3 cm (``pointcloud0``, as every simulated flight).

The shipped ``firefly`` vehicle file has no thrust or moment coefficient (EuRoC does not publish
them); :func:`flyable` flies it with RotorS's Firefly constants (those of the built-in ``hex``), which
``vehicle.yaml`` and ``truth.yaml`` then hold.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from uavturb.errors import InputError
from uavturb.io.recording import Recording
from uavturb.io.vehicle_file import SHIPPED_DIR, load_vehicle
from uavturb.physics.vehicle import HEXAROTOR, Vehicle
from uavturb.scene.indoor import Scene
from uavturb.scene.layouts import floor_boxes, room_size
from uavturb.scene.camera import EUROC_CAM0, least_body_height
from uavturb.sim.core.signals import Reference
from uavturb.sim.flights.plans import EUROC_ROOM, euroc_room

#: the flight kind (``uavturb generate flight --kind euroc_room``)
KIND = "euroc_room"


def landed_height() -> float:
    """Body origin over the floor when landed [m]: cam0 (0.13 m under it) 3 cm over the floor."""
    return round(least_body_height(EUROC_CAM0.name), 3)


def reference(duration: float, seed: int, max_yaw_acc: float = 0.5, room: Scene | None = None) -> Reference:
    """The flight plan: :func:`~uavturb.sim.flights.plans.euroc_room` in ``room`` (default
    :data:`~uavturb.sim.flights.plans.EUROC_ROOM`), landed at :func:`landed_height`; ``max_yaw_acc`` rad/s^2."""
    return euroc_room(duration, seed, room=EUROC_ROOM if room is None else room, rest_height=landed_height(),
                      max_yaw_acc=max_yaw_acc)


def _same_geometry(a: Vehicle, b: Vehicle) -> bool:
    return (a.rotor_count == b.rotor_count and np.isclose(a.arm_length, b.arm_length)
            and np.isclose(a.rotor_radius, b.rotor_radius)
            and np.allclose(a.rotor_angles_deg, b.rotor_angles_deg)
            and tuple(a.rotor_directions) == tuple(b.rotor_directions))


def flyable(vehicle: Vehicle) -> Vehicle:
    """``vehicle`` with the constants a simulation needs.

    A vehicle with the Firefly's rotor geometry and no thrust or moment coefficient (the shipped
    ``firefly`` file) gets RotorS's Firefly constants (the built-in ``hex``: ``k_T`` 8.54858e-6
    N/(rad/s)^2, ``k_M`` 0.016 ``k_T``, top speed 838 rad/s); any other incomplete vehicle is an error.
    """
    if vehicle.thrust_coefficient is not None and vehicle.moment_coefficient is not None:
        return vehicle
    if not _same_geometry(vehicle, HEXAROTOR):
        raise InputError(vehicle.name, "thrust_coefficient and moment_coefficient are needed to simulate it")
    changes = {k: getattr(HEXAROTOR, k) for k in ("thrust_coefficient", "moment_coefficient", "max_rotor_speed")
               if getattr(vehicle, k) is None}
    return vehicle.with_params(**changes)


def with_vi_sensor(vehicle: Vehicle) -> Vehicle:
    """``vehicle`` carrying EuRoC's VI-sensor: its ``T_BS`` (S in B) kept when it has one, else the
    Firefly's (``uavturb/vehicles/firefly.yaml``)."""
    if not vehicle.sensor_is_body:
        return vehicle
    return vehicle.with_params(T_BS=load_vehicle(SHIPPED_DIR / f"{EUROC_CAM0.vehicle}.yaml").T_BS)


def with_cam0(rec: Recording) -> Recording:
    """``rec`` with EuRoC's cam0 (``sensor.yaml`` alone: intrinsics, 20 Hz, ``T_BS`` relative to S)."""
    return replace(rec, cam0=EUROC_CAM0.sensor())


def truth_entry() -> dict:
    """What ``truth.yaml`` says of the stand-in (camera, room, landed height)."""
    return {"cam0": EUROC_CAM0.name, "cam0_source": EUROC_CAM0.source, "landed_height_m": landed_height(),
            "room": {"size_m": list(room_size(EUROC_ROOM)), "ceiling_m": float(EUROC_ROOM.ceiling_height),
                     "boxes": [list(b) for b in floor_boxes(EUROC_ROOM)]}}
