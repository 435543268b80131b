"""``uavturb generate flight|sim|normals|merge``: the simulator's generators as commands."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from uavturb.errors import InputError
from uavturb.io.recording import Recording


def parse_wind_speed(text: str | None) -> tuple[float, float] | None:
    """``"vx,vy"`` [m/s] -> ``(vx, vy)``; ``None`` stays ``None``."""
    if text is None:
        return None
    try:
        vx, vy = (float(x) for x in str(text).split(","))
    except ValueError:
        raise InputError("--wind-speed", f"expected vx,vy in m/s (e.g. 1.5,-0.5), got '{text}'") from None
    return vx, vy


def generate_flight_command(*, vehicle: str = "hex", effects: str = "none", duration: float = 60.0,
                            kind: str = "mixed", seed: int = 0, noise: str = "realistic",
                            out: str | Path | None = None, no_imu: bool = False, rate_hz: float | None = None,
                            jitter_ms: float = 0.0, fixed_heading: bool = False, motor_commands: bool = False,
                            wind_speed: str | None = None, accel_bias_walk: float = 0.0, sensor_frame: str = "body",
                            mass_error: float = 0.0, ground_contact_s: float = 0.0,
                            position_hold_hz: float | None = None, rotor_hold_hz: float | None = None,
                            rotor_delay_s: float = 0.0, thrust_level: float = 1.0, thrust_tilt_deg: float = 0.0,
                            thrust_tilt_azimuth_deg: float = 0.0, rotor_plane_z: float = 0.0,
                            measured_rotors: bool = False, battery_voltage: float | None = None,
                            heading_deg: float | None = None) -> Recording:
    """``uavturb generate flight``: a simulated flight in the EuRoC layout, with the troubles of real
    recordings asked for (:class:`uavturb.sim.flights.conditions.Conditions`) and their truth in ``truth.yaml``.

    Takes the command's arguments as text (``effects``, ``noise``, ``wind_speed``) and calls
    :func:`uavturb.sim.flights.conditions.generate_conditioned_flight`; the library's flight without the
    troubles is :func:`uavturb.sim.flights.simulate.generate_flight`."""
    from uavturb.sim.flights.conditions import Conditions, generate_conditioned_flight
    from uavturb.sim.flights.sensors import SensorNoise

    if noise not in ("realistic", "none"):
        raise InputError("--noise", f"unknown value '{noise}' (allowed: realistic, none)")
    sensor_noise = SensorNoise() if noise == "realistic" else SensorNoise.none()
    cond = Conditions(no_imu=no_imu, rate_hz=rate_hz, jitter_ms=jitter_ms, fixed_heading=fixed_heading,
                      heading_deg=heading_deg,
                      motor_commands=motor_commands, wind_speed=parse_wind_speed(wind_speed),
                      accel_bias_walk=accel_bias_walk, sensor_frame=sensor_frame, mass_error=mass_error,
                      ground_contact_s=ground_contact_s, position_hold_hz=position_hold_hz,
                      rotor_hold_hz=rotor_hold_hz, rotor_delay_s=rotor_delay_s, thrust_level=thrust_level,
                      thrust_tilt_deg=thrust_tilt_deg, thrust_tilt_azimuth_deg=thrust_tilt_azimuth_deg,
                      rotor_plane_z=rotor_plane_z, measured_rotors=measured_rotors, battery_voltage=battery_voltage)
    return generate_conditioned_flight(vehicle=vehicle, effects=effects, duration=duration, kind=kind, seed=seed,
                                       conditions=cond, noise=sensor_noise, out=out).recording


def preset_overrides(items: Sequence[str]) -> dict:
    """``--set KEY=VALUE`` options as a dict; values are read as YAML scalars (``64``, ``0.5``, ``true``)."""
    import yaml

    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise InputError("--set", f"expected KEY=VALUE, got {item!r}")
        try:
            out[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError:
            raise InputError(f"--set {key.strip()}", f"cannot read value {value!r}") from None
    return out


def generate_sim(preset: str, out: str | Path, *, workers: int = 1, seed: int = 0, shard: str | None = None,
                 executor: str = "local", address: str | None = None, **overrides) -> str:
    """``uavturb generate sim``: training shards; ``overrides`` change preset fields. Returns the summary line.

    ``executor="ray"``: one Ray task per trajectory, on the cluster at ``address`` or on a local
    Ray instance with ``workers`` CPUs; the arrays are the same as with ``local``.
    """
    from uavturb.sim.dataset import generation

    if executor == "ray":
        from uavturb.runs.executors import ray_session

        with ray_session(address, num_cpus=workers):
            m = generation.generate_sim(preset, out, workers=workers, seed=seed, shard=shard, executor="ray",
                                     **overrides)
    else:
        if address:
            raise InputError("--address", "only with --executor ray")
        m = generation.generate_sim(preset, out, workers=workers, seed=seed, shard=shard, executor=executor,
                                 **overrides)
    return generation.describe(m.root)


def generate_normals(preset: str, out: str | Path, *, workers: int = 1, seed: int = 0, irs: str | None = None,
                     size: int = 128, **overrides) -> str:
    """``uavturb generate normals``: pre-training pairs (rendered, or converted from IRS)."""
    from uavturb.sim.dataset import pretraining_pairs

    if irs is not None:
        meta = pretraining_pairs.import_irs(irs, out, size=size)
    else:
        meta = pretraining_pairs.generate_normals(preset, out, workers=workers, seed=seed, **overrides)
    return f"wrote {Path(out) / 'pairs'}: {meta['count']} pairs of {meta['image_size'][0]}x{meta['image_size'][1]} px"


def generate_merge(dirs: Sequence[str | Path], out: str | Path) -> str:
    """``uavturb generate merge``: join shard folders."""
    from uavturb.sim.dataset import generation

    m = generation.merge_datasets(dirs, out)
    return generation.describe(m.root)

