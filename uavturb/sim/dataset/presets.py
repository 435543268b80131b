"""Presets of the simulated datasets (``uavturb generate sim|normals --preset NAME``).

A preset fixes everything that determines the arrays of a dataset except the seed: which
scenes and how they are split, how many trajectories of which length, the camera, the
vehicle, the effects and the simulator's time steps. Its fields are the dataset config
stored (with its hash) in ``manifest.json``; two runs with the same preset, overrides and
seed write identical arrays.

"Preset" means this one thing: a named simulated dataset, the value of ``--preset`` (stored under
the key ``preset`` of every manifest's config, so part of its hash). Vehicles are built-in
(``quad``, ``hex``) or shipped (``firefly``), never presets.

A preset's fields are changed with the one override syntax of the package
(``uavturb generate sim --preset quick --out DIR width=64 effects.ground_effect.mu=2.5``; ``--set
KEY=VALUE`` is an alias): :func:`parse_preset_overrides` types each value by :class:`SimPreset`'s
fields, which declare their ranges (:func:`uavturb.schema.allowed`).

=========  ======  =========  ============  ==========  ===========  ============
preset     scenes  split      trajectories  samples     image        pairs
=========  ======  =========  ============  ==========  ===========  ============
tiny       3       1/1/1      3             123         32 x 32      24
quick      8       5/1/2      16            ~6,700      128 x 128    400
medium     27      18/3/6     60            ~25,000     32 x 32      2,000
paper      68      43/9/16    531           ~360,000    128 x 128    22,705
=========  ======  =========  ============  ==========  ===========  ============

Trajectories are planned by :func:`uavturb.sim.dataset.planning.plan_trajectory` (random points
ordered by Christofides, A* around walls, take-offs, low hovers, landings and edge passes);
their length follows from the number of random points (``plan_points``, drawn per
trajectory): about 14 s with 1 point, 27 s with 2, 53 s with 3 on the generated scenes, so
``paper``'s mix (2, 2, 2, 3) averages about 34 s = 676 samples at 20 Hz, the paper's
358,828 / 531.

``paper`` follows the paper (section "Large-scale generation of simulated UAV trajectory
data": 68 scenes, 43/9/16, 531 trajectories, 358,828 samples; IRS pre-training on 22,705
depth/normal pairs). ``quick`` finishes in a few minutes on 2 cores and is what ``make demo``
uses; ``tiny`` is for tests. ``medium`` is the smallest scale at which Table 1's rows can
separate on a 2-core CPU (18 training scenes instead of quick's 5, 6 test scenes, 32 x 32 px
so that the ablation sweep ``sweeps/ablation.yaml --profile medium`` takes ~10.5 min per seed;
generation ~1 min with 2 workers); it is written to ``data/medium/sim`` and
``data/medium/pairs`` by convention.

Units: seconds, hertz, metres, degrees, pixels.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import Any

from uavturb.errors import InputError
from uavturb.physics.effects import DEFAULT_EFFECTS
from uavturb.scene.camera import CAMERA_NAMES
from uavturb.schema import allowed, apply_overrides, check_keys, check_values, parse_overrides


@dataclass(frozen=True)
class SimPreset:
    """What a simulated dataset is made of.

    Each field declares the values it accepts (:func:`uavturb.schema.allowed`); :meth:`check`
    tests them and the relations between fields.

    Attributes
    ----------
    name : str
    n_scenes, n_train, n_val, n_test : int
        Scenes (procedural, seeds ``0 .. n_scenes - 1``) and their split
        (:func:`uavturb.scene.procedural.split_scenes` with ``split_seed``).
    split_seed : int
        Seed of the scene permutation (independent of the dataset seed: the split of a
        preset never changes).
    trajectories : int
        Trajectories in all; spread over the scenes as evenly as possible (the first
        ``trajectories % n_scenes`` scenes get one more).
    plan_points : tuple of int
        Random points of a trajectory's plan, drawn uniformly from this tuple per trajectory.
    max_seconds : float, s
        Cut flights longer than this (0: fly the whole plan, which ends landed).
    plan : dict
        Overrides of :class:`uavturb.sim.dataset.planning.PlanConfig` fields (``n_points`` excepted).
    camera_hz : float, Hz
        Sample (camera) rate.
    width, height : int, px
    yfov_deg : float, deg
        Vertical field of view.
    pitch_deg : float, deg
        Downward pitch of the forward camera relative to body +x.
    camera : str
        Camera of :mod:`uavturb.scene.camera`: ``forward`` (default: at the body origin, ``yfov_deg``
        and ``pitch_deg`` above) or a calibrated one (``euroc_cam0``: its intrinsics scaled to
        ``width x height`` and its mount on the body; ``yfov_deg`` and ``pitch_deg`` then unused).
        A camera hanging under the body origin raises the plan's landed and low-hover heights so
        that it stays 3 cm over the surface (:func:`uavturb.sim.dataset.flying.plan_config`: 0.16 m for
        ``euroc_cam0``). The manifest's
        config names it only when it is not ``forward`` (existing datasets keep their hash).
    normals : bool
        Also store camera-frame surface normals per sample.
    rgb : bool
        Also store a colour image per sample (``rgb.npy``, uint8, beside the contract's arrays).
    vehicle : str
        Built-in vehicle (``quad``, ``hex``), shipped (``firefly``) or ``vehicle.yaml``
        (:func:`uavturb.io.vehicle_file.named_vehicle`).
    effects : dict
        Effects of ``effects.md`` simulated (``{name: {param: value}}``); ``ground_effect``
        gives the ``mu`` of the stored ``f_a``.
    controller : str
        ``'auto'`` (the CasADi MPC of :mod:`uavturb.sim.dataset.flying` when installed, else
        the geometric controller), ``'mpc'`` or ``'geometric'``.
    physics_dt : float, s
        Integration step of the physics of MPC flights (the MPC runs at its own rate,
        25 Hz; at 100 Hz physics the flights equal those at 200 Hz to 1e-7 m of tracking).
    geometric_dt : float, s
        Physics step and control period of geometric-controller flights (the 50 g
        quadrotor needs 200 Hz control).
    pairs : int
        Depth/normal pairs of ``generate normals`` (from the training scenes).
    pairs_chunk : int
        Pairs per resumable chunk of ``generate normals``.
    """

    name: str = "custom"
    n_scenes: int = allowed(8, ge=1)
    n_train: int = allowed(5, ge=1)
    n_val: int = allowed(1, ge=0)
    n_test: int = allowed(2, ge=0)
    split_seed: int = 0
    trajectories: int = allowed(16, ge=1)
    plan_points: tuple = allowed((1, 2), ge=1, nonempty=True, text="a non-empty list of integers >= 1")
    max_seconds: float = allowed(0.0, ge=0)                  # s
    plan: dict = field(default_factory=dict)               # keys: PlanConfig's (checked in check())
    camera_hz: float = allowed(20.0, gt=0)                  # Hz
    width: int = allowed(128, ge=1)                         # px
    height: int = allowed(128, ge=1)                        # px
    yfov_deg: float = allowed(70.0, gt=0, lt=180)           # deg
    pitch_deg: float = 20.0                                 # deg
    camera: str = allowed("forward", choices=CAMERA_NAMES)
    normals: bool = False
    rgb: bool = False
    vehicle: str = "quad"
    effects: dict = field(default_factory=lambda: {k: dict(v) for k, v in DEFAULT_EFFECTS.items()})
    controller: str = allowed("auto", choices=("auto", "mpc", "geometric"))
    physics_dt: float = allowed(0.01, gt=0)                 # s
    geometric_dt: float = allowed(0.005, gt=0)              # s
    pairs: int = allowed(400, ge=1)
    pairs_chunk: int = allowed(256, ge=1)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict of every field (``camera`` left out when it is ``forward``)."""
        d = asdict(self)
        d["plan_points"] = [int(k) for k in self.plan_points]
        if d["camera"] == "forward":  # the default camera leaves the config (and its hash) as before
            del d["camera"]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "SimPreset":
        """Inverse of :meth:`to_dict` (a manifest's ``config["preset"]``)."""
        d = dict(d)
        if "plan_points" in d:
            d["plan_points"] = tuple(d["plan_points"])
        return cls(**d)

    def check(self) -> "SimPreset":
        """Raise :class:`InputError` naming the field when a value is not allowed: each field's
        range from its declaration (:func:`uavturb.schema.check_values`), then the relations
        between fields (:meth:`_check_relations`)."""
        check_values(self, prefix=f"preset {self.name}: ")
        self._check_relations()
        return self

    def _check_relations(self) -> None:
        """The split sums to the scenes, the plan's keys are PlanConfig's, the time steps divide the
        sample period, the effects hold the ground effect."""
        def bad(key: str, problem: str) -> InputError:
            return InputError(f"preset {self.name}: {key}", problem)

        if self.n_train + self.n_val + self.n_test != self.n_scenes:
            raise bad("n_train/n_val/n_test", f"sum to {self.n_train + self.n_val + self.n_test}, "
                                              f"not n_scenes = {self.n_scenes}")
        # late: the CLI lists the presets while it builds its parser, and planning pulls in the scene's meshes
        from uavturb.sim.dataset.planning import PlanConfig

        known = sorted({f.name for f in fields(PlanConfig)} - {"n_points"})
        check_keys(self.plan, known, lambda k: f"preset {self.name}: plan.{k}", noun="PlanConfig field")
        rec = 1.0 / self.camera_hz
        for key in ("physics_dt", "geometric_dt"):
            step = getattr(self, key)
            n = round(rec / step)
            if n < 1 or abs(n * step - rec) > 1e-9:
                raise bad(key, f"1 / camera_hz = {rec:g} s must be a whole multiple of it, got {step}")
        if "ground_effect" not in self.effects:
            raise bad("effects", "must hold ground_effect (its mu defines the stored f_a)")


PRESETS: dict[str, SimPreset] = {
    "tiny": SimPreset(name="tiny", n_scenes=3, n_train=1, n_val=1, n_test=1, trajectories=3, plan_points=(1,),
                      max_seconds=2.0, width=32, height=32, pairs=24, pairs_chunk=10),
    "quick": SimPreset(name="quick"),
    "medium": SimPreset(name="medium", n_scenes=27, n_train=18, n_val=3, n_test=6, trajectories=60,
                        plan_points=(1, 2), width=32, height=32, pairs=2000, pairs_chunk=500),
    "paper": SimPreset(name="paper", n_scenes=68, n_train=43, n_val=9, n_test=16, trajectories=531,
                       plan_points=(2, 2, 2, 3), pairs=22705, pairs_chunk=512),
}


def get_preset(name: str | SimPreset, /, **overrides: Any) -> SimPreset:
    """A preset by name (``tiny``, ``quick``, ``medium``, ``paper``) with fields overridden.

    ``overrides``: field values (``width=64``) or, with dotted keys as
    :func:`uavturb.schema.parse_overrides` gives them, values inside a mapping field
    (``**{"effects.ground_effect.mu": 2.0}``).

    Raises
    ------
    InputError
        Unknown preset, unknown field (named, with the closest one), or a value out of range.
    """
    if isinstance(name, SimPreset):
        base = name
    elif name in PRESETS:
        base = PRESETS[name]
    else:
        raise InputError("--preset", f"unknown preset {name!r} (known: {', '.join(PRESETS)})")
    return apply_overrides(base, overrides, lambda k: f"preset {base.name}: {k}").check()


def parse_preset_overrides(items: list[str], name: str = "custom", option: str = "override") -> dict[str, Any]:
    """``KEY=VALUE`` strings (``uavturb generate sim|normals``) as overrides of :func:`get_preset`,
    typed by :class:`SimPreset` (:func:`uavturb.schema.parse_overrides`): ``width=abc`` fails naming
    ``preset NAME: width``."""
    return parse_overrides(items, SimPreset, lambda k: f"preset {name}: {k}", option=option)
