"""The schema of a flight's conditions: which troubles of a real recording ``uavturb generate flight``
reproduces (:mod:`uavturb.sim.flights.conditions` does it and writes their truth).

Each field of :class:`Conditions` declares its default, the values it accepts, its help text and
metavar (:func:`uavturb.schema.allowed`); the command's options are generated from these fields
(``uavturb/cli.py``), so a new trouble is one field here. A light module on purpose: the command
line builds its parser from it at every start.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from uavturb.errors import InputError
from uavturb.schema import allowed, check_keys, check_values, field_types, option_name, read_value

SENSOR_FRAMES = ("body", "euroc")


@dataclass(frozen=True)
class Conditions:
    """The troubles of a real recording to reproduce (all off by default; see
    :mod:`uavturb.sim.flights.conditions`). Errors name the ``generate flight`` option
    (``--rate-hz``) of the field at fault."""

    no_imu: bool = allowed(False, help="no imu0: motion capture only")
    rate_hz: float | None = allowed(None, gt=0, le=200, unit="Hz (the simulator records at 200 Hz)",
                                    help="ground truth and rotors at this rate (IMU stays 200 Hz)")
    jitter_ms: float = allowed(0.0, ge=0, unit="ms", help="sampling-time jitter of those streams, +- ms")
    fixed_heading: bool = allowed(False, help="the reference's yaw never changes")
    heading_deg: float | None = allowed(None, metavar="DEG", text="a finite angle [deg]",
                                        help="with --fixed-heading: the heading held (default the reference's "
                                             "initial one)")
    motor_commands: bool = allowed(False, help="rotors0 holds commands u in [0,1]; true speed w = a + b u; "
                                               "rotor_speed_scale exact at hover")
    wind_speed: tuple[float, float] | None = allowed(None, length=2, metavar="VX,VY",
                                                     text="two finite numbers vx,vy [m/s]",
                                                     help="steady wind [m/s, world]: rotor and body drag act on the "
                                                          "airspeed v - v_wind")
    accel_bias_walk: float = allowed(0.0, ge=0, unit="m/s^3/sqrt(Hz)", metavar="SIGMA",
                                     help="accelerometer bias random walk, m/s^3/sqrt(Hz); the state file keeps the "
                                          "initial bias")
    sensor_frame: str = allowed("body", choices=SENSOR_FRAMES,
                                help="streams in a EuRoC-like sensor frame S (T_BS in vehicle.yaml, 10 cm lever arm)")
    mass_error: float = allowed(0.0, gt=-0.5, lt=0.5, metavar="FRACTION",
                                help="vehicle.yaml's mass is the simulated one times 1 + FRACTION")
    ground_contact_s: float = allowed(0.0, ge=0, le=30, unit="s", metavar="S",
                                      help="S seconds on the landing gear, rotors spinning, at the start and the end "
                                           "(kinds that land)")
    position_hold_hz: float | None = allowed(None, gt=0, unit="Hz", metavar="HZ",
                                             help="ground-truth rows keep their rate but update at HZ "
                                                  "(bit-identical repeats)")
    rotor_hold_hz: float | None = allowed(None, gt=0, unit="Hz", metavar="HZ",
                                          help="rotors0 rows keep their rate but update at HZ (bit-identical repeats)")
    rotor_hold_staggered: bool = allowed(False, help="with --rotor-hold-hz: each rotor's speed updates at HZ on its "
                                                     "own, one ESC after another (round-robin telemetry)")
    rotor_delay_s: float = allowed(0.0, ge=0, lt=1, unit="s", metavar="S",
                                   help="rotors0 timestamps S seconds late (the row at t holds the value at t - S)")
    thrust_level: float = allowed(1.0, gt=0.5, lt=1.5, metavar="FACTOR",
                                  help="true k_T is vehicle.yaml's times FACTOR (a per-recording thrust level)")
    thrust_tilt_deg: float = allowed(0.0, ge=0, lt=10, unit="deg", metavar="DEG",
                                     help="thrust axis tilted DEG from the airframe's z (attitude and IMU of the "
                                          "airframe)")
    thrust_tilt_azimuth_deg: float = allowed(0.0, metavar="DEG", text="a finite angle [deg]",
                                             help="direction of that tilt in the airframe's x-y plane, from +x "
                                                  "towards +y")
    rotor_plane_z: float = allowed(0.0, gt=-0.5, lt=0.5, unit="m", metavar="M",
                                   help="rotor plane M metres above the body origin (negative: below), in vehicle.yaml")
    measured_rotors: bool = allowed(False, help="rotors0 holds measured (actual) rotor speeds; vehicle.yaml "
                                                "rotor_speed_source: measured")
    battery_voltage: float | None = allowed(None, gt=0, lt=100, unit="V", metavar="V",
                                            help="write battery0: the voltage from V, sagging over the flight")
    battery_load_sag: float = allowed(0.0, ge=0, lt=0.5, metavar="FRACTION",
                                      help="with --battery-voltage: the share of V the voltage loses at hover under "
                                           "load, growing as thrust^1.5 (0.05-0.1 on small packs)")

    def __post_init__(self) -> None:
        check_values(self, name=option_name)
        self._check_relations()

    def _check_relations(self) -> None:
        """What one field's range cannot say: rules between fields."""
        period_ms = 1000.0 / (self.rate_hz or 200.0)
        if self.jitter_ms >= period_ms / 2:
            raise InputError("--jitter-ms", f"must be under half the sampling period ({period_ms / 2:g} ms) so that "
                                            f"timestamps stay in order, got {self.jitter_ms}")
        if self.heading_deg is not None and not self.fixed_heading:
            raise InputError("--heading-deg", f"needs --fixed-heading, got {self.heading_deg}")
        if self.no_imu and self.accel_bias_walk > 0:
            raise InputError("--accel-bias-walk", "needs an IMU (it cannot be combined with --no-imu)")
        row_hz = self.rate_hz or 200.0
        for flag, hz in (("--position-hold-hz", self.position_hold_hz), ("--rotor-hold-hz", self.rotor_hold_hz)):
            if hz is not None and not hz < row_hz:
                raise InputError(flag, f"must be in (0, {row_hz:g}) Hz (below the stream's row rate), got {hz}")
        if self.rotor_hold_staggered and self.rotor_hold_hz is None:
            raise InputError("--rotor-hold-staggered", "needs --rotor-hold-hz (the rate each rotor's speed updates at)")
        if self.thrust_tilt_deg > 0 and self.sensor_frame != "body":
            raise InputError("--thrust-tilt-deg", "cannot be combined with --sensor-frame euroc")
        if self.battery_load_sag > 0 and self.battery_voltage is None:
            raise InputError("--battery-load-sag", "needs --battery-voltage (the voltage it sags from)")
        if self.measured_rotors and self.motor_commands:
            raise InputError("--measured-rotors", "cannot be combined with --motor-commands (rotors0 holds one or "
                                                  "the other)")

    @classmethod
    def from_options(cls, options: dict[str, Any]) -> "Conditions":
        """Conditions from ``generate flight``'s options (``{"rate_hz": 50.0, "wind_speed": "1,-0.5"}``):
        text is read by the field's type (:func:`uavturb.schema.read_value`); unknown keys fail."""
        types = field_types(cls)
        check_keys(options, list(types), option_name, noun="condition")
        return cls(**{k: read_value(v, types[k], option_name(k)) if isinstance(v, str) and types[k] is not str else v
                      for k, v in options.items()})

    @property
    def resampled(self) -> bool:
        return self.rate_hz is not None or self.jitter_ms > 0


def condition_fields() -> list[dataclasses.Field]:
    """The fields of :class:`Conditions`, in the order ``generate flight --help`` lists them."""
    return list(dataclasses.fields(Conditions))
