"""``uavturb generate flight|sim|normals|merge``: the simulator's generators as commands."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

from uavturb.errors import InputError
from uavturb.io.recording import Recording
from uavturb.sim.dataset import generation, pretraining_pairs
from uavturb.sim.dataset.presets import parse_preset_overrides
from uavturb.sim.flights.condition_schema import Conditions
from uavturb.sim.flights.conditions import generate_conditioned_flight
from uavturb.sim.flights.sensors import SensorNoise


def generate_flight_command(*, vehicle: str = "hex", effects: str = "none", duration: float = 60.0,
                            kind: str = "mixed", seed: int = 0, noise: str = "realistic",
                            out: str | Path | None = None, **conditions: Any) -> Recording:
    """``uavturb generate flight``: a simulated flight in the EuRoC layout, with the troubles of real
    recordings asked for and their truth in ``truth.yaml``.

    ``conditions`` are the command's trouble options, the fields of
    :class:`uavturb.sim.flights.condition_schema.Conditions` (``rate_hz=50.0``, ``wind_speed="1,-0.5"``:
    text is read by the field's type; an unknown or bad one fails naming its option). Calls
    :func:`uavturb.sim.flights.conditions.generate_conditioned_flight`; the library's flight without
    the troubles is :func:`uavturb.sim.flights.simulate.generate_flight`."""
    if noise not in ("realistic", "none"):
        raise InputError("--noise", f"unknown value '{noise}' (allowed: realistic, none)")
    sensor_noise = SensorNoise() if noise == "realistic" else SensorNoise.none()
    cond = Conditions.from_options(conditions)
    return generate_conditioned_flight(vehicle=vehicle, effects=effects, duration=duration, kind=kind, seed=seed,
                                       conditions=cond, noise=sensor_noise, out=out).recording


def preset_overrides(items: Sequence[str], preset: str = "custom") -> dict[str, Any]:
    """``KEY=VALUE`` overrides of preset fields (``generate sim|normals``: positional, or each after
    ``--set``, its alias) typed by the preset's schema
    (:func:`uavturb.sim.dataset.presets.parse_preset_overrides`)."""
    return parse_preset_overrides(list(items), preset)


def generate_sim(preset: str, out: str | Path, *, workers: int = 1, seed: int = 0, shard: str | None = None,
                 executor: str = "local", address: str | None = None, **overrides) -> str:
    """``uavturb generate sim``: training shards; ``overrides`` change preset fields. Returns the summary line.

    ``executor="ray"``: one Ray task per trajectory, on the cluster at ``address`` or on a local
    Ray instance with ``workers`` CPUs; the arrays are the same as with ``local``.
    """
    if executor == "ray":
        # late: the run platform's executors load Lightning, which a local generation never needs
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
    if irs is not None:
        meta = pretraining_pairs.import_irs(irs, out, size=size)
    else:
        meta = pretraining_pairs.generate_normals(preset, out, workers=workers, seed=seed, **overrides)
    return f"wrote {Path(out) / 'pairs'}: {meta['count']} pairs of {meta['image_size'][0]}x{meta['image_size'][1]} px"


def generate_merge(dirs: Sequence[str | Path], out: str | Path) -> str:
    """``uavturb generate merge``: join shard folders."""
    m = generation.merge_datasets(dirs, out)
    return generation.describe(m.root)
