"""The flights' rows in the air that the gap finder fits: rotor speeds checked against vehicle.yaml's thrust
coefficient, landings aligned, ground contact left out, and what the torques read of the rotor columns' order and of
the commands' timing."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from uavturb.errors import InputError
from uavturb.gap.design import GapData, gap_data
from uavturb.gap.landed_heights import LandedHeights
from uavturb.gap.preparation import contact_masks, landings_aligned
from uavturb.physics.dynamics import GRAVITY
from uavturb.sysid.command_lag import CommandLag, command_lag
from uavturb.sysid.rotor_order import OTHER as OTHER_ORDER
from uavturb.sysid.rotor_order import REORDER, RotorOrder, rotor_order

#: thrust over weight, the median while all rotors spin, above which vehicle.yaml's thrust coefficient cannot be that
#: of the recorded speeds (flights hover at about one; racing quadrotors peak at 5-10, not for most of a flight)
MAX_THRUST_TO_WEIGHT = 3.0


def check_thrust_scale(fd: Any, vehicle: Any, path: str) -> None:
    """With vehicle.yaml's thrust coefficient, the recorded rotor speeds (``fd``'s) carry more than 30 % of the weight
    at some time and under :data:`MAX_THRUST_TO_WEIGHT` times it most of the time; otherwise refused in one line
    (rotors0 in other units than rad/s, or a thrust coefficient or mass off)."""
    weight = vehicle.mass * GRAVITY
    thrust = vehicle.thrust_coefficient * np.sum(fd.rotor_speeds**2, axis=1)
    where = f"{path}/mav0/rotors0/data.csv"
    most = float(np.max(thrust))
    if most < 0.3 * weight:
        raise InputError(where, f"its rotor speeds never carry more than {100 * most / weight:.2g} % of the weight "
                                f"with vehicle.yaml's thrust_coefficient {vehicle.thrust_coefficient:.4g} "
                                "N/(rad/s)^2: a flight that never took off, speeds in other units than rad/s (Hz, rpm: "
                                "rotor_speed_scale converts) or a thrust coefficient off")
    spinning = np.all(fd.rotor_speeds > 0, axis=1)
    typical = float(np.median(thrust[spinning])) if spinning.any() else 0.0
    if typical > MAX_THRUST_TO_WEIGHT * weight:
        raise InputError(where, f"its rotor speeds would lift {typical / weight:.3g} times the weight (the median "
                                f"while all rotors spin) with vehicle.yaml's thrust_coefficient "
                                f"{vehicle.thrust_coefficient:.4g} N/(rad/s)^2, where a flight needs about one: speeds "
                                "in other units than rad/s (rpm: rotor_speed_scale 0.10472 converts), or a thrust "
                                "coefficient or mass off")


def flight_rows(fds: list, vehicles: Sequence[Any], paths: Sequence[str], *, sim_forces: bool = True,
                read_order: bool = False) -> tuple[GapData, list[dict[str, Any]], LandedHeights]:
    """The flights' rows in the air (ground contact found and left out), the report's ``ground_contact`` and the
    recordings' landed heights, each flight's heights moved so that they land at one
    (:func:`~uavturb.gap.preparation.landings_aligned`), and its forces with its own vehicle.yaml's mass
    (``vehicles``, one per flight: one vehicle, io.reader checks, whose batteries may weigh differently). Rotor
    speeds at odds with vehicle.yaml's thrust coefficient are refused (:func:`check_thrust_scale`). ``fds`` is
    emptied as the rows are built (its places set to None: :func:`~uavturb.gap.design.gap_data`'s ``release``);
    ``sim_forces``: the simulator models effects, computed on the flights at full rate (``gap_data``'s);
    ``read_order``: read which order of the rotor columns the torques follow (:func:`rotor_columns_order`, the
    rows' :attr:`~uavturb.gap.design.GapData.rotor_order`; once, on the recordings as read)."""
    for fd, vehicle_of, path in zip(fds, vehicles, paths):
        if vehicle_of.thrust_coefficient:
            check_thrust_scale(fd, vehicle_of, path)
    vehicle = vehicles[0]
    fds[:], landed = landings_aligned(fds, vehicle)
    contact, contact_report = contact_masks(fds, vehicle, paths)
    masses = [v.mass for v in vehicles]
    order = rotor_columns_order(fds, vehicle, contact) if read_order else None
    torque = torques_timed(fds, vehicle, contact) if order is None or order.verdict != OTHER_ORDER else None
    data = gap_data(fds, vehicle.mass, vehicle.rotor_radius, k_T_guess=vehicle.thrust_coefficient, release=True,
                    arm_length=vehicle.arm_length, exclude=contact, masses=None if len(set(masses)) == 1 else masses,
                    sim_forces=sim_forces)
    data.torque_lag = torque
    data.rotor_order = order
    return data, contact_report, landed


#: rows in the air at most that the rotor columns' order is read on (every k-th row beyond): a correlation over 10,000
#: rows has a standard error near 0.01-0.02 (fewer where the rows, thinned, are still correlated over about 50 ms),
#: well under the orders' margin of 0.1 (``rotor_order.ORDER_MARGIN``)
ORDER_ROWS = 10_000


def rotor_columns_order(fds: list, vehicle: Any, contact: list[np.ndarray]) -> RotorOrder | None:
    """Which order of the rotor columns the roll and pitch accelerations follow in the air
    (:func:`uavturb.sysid.rotor_order.rotor_order`, as ``identify`` reads it). The forces do not depend on it (the
    thrust is a sum over the rotors); the torques, and the torques' timing of commanded speeds, do."""
    usable = [~c & np.isfinite(fd.dw).all(axis=1) for fd, c in zip(fds, contact)]
    stride = -(-sum(int(u.sum()) for u in usable) // ORDER_ROWS)
    if stride > 1:  # every stride-th row in the air: the time stays bounded (twelve one-minute walks: 0.44 -> 0.07 s)
        usable = [u & (np.cumsum(u) % stride == 0) for u in usable]
    return rotor_order([fd.matched(fd.rotor_speeds**2) for fd in fds], [fd.dw for fd in fds], vehicle.mixer(),
                       dt=[fd.dt for fd in fds], usable=usable)


def rotor_order_lines(order: RotorOrder | None, recordings: Sequence) -> list[str]:
    """The streams' line where the rotor columns follow another order than vehicle.yaml's angles: what it changes
    (the torques' timing, not the forces) and the fix; nothing otherwise (the order is in ``facts.rotor_order``)."""
    if order is None or order.verdict != OTHER_ORDER:
        return []
    names = list(dict.fromkeys(r.name for r in recordings))
    where = f"{names[0]}/mav0/rotors0" if len(names) == 1 else f"mav0/rotors0 of {', '.join(names)} (read together)"
    return [f"{where}: {order.sentence()}. The forces read here do not depend on it (the thrust is a sum over the "
            f"rotors); the torques do, so the commands' timing is not read on them: {REORDER}"]


def torques_timed(fds: list, vehicle: Any, contact: list[np.ndarray]) -> CommandLag | None:
    """How far the roll and pitch torques lag commanded rotor speeds, timed on the angular acceleration in the air
    (:func:`uavturb.sysid.command_lag.command_lag`, as ``identify`` reads it): a motor-lag explanation checks its
    thrust's lag against it. None for measured speeds (the rotors' own) and held streams (a hold reads as a lag)."""
    if vehicle.rotor_speed_source == "measured" or any(fd.rotor_fresh is not None for fd in fds):
        return None
    masks = [~c & np.isfinite(fd.dw).all(axis=1) for fd, c in zip(fds, contact)]
    return command_lag(fds, masks, vehicle)
