"""One schema system (:mod:`uavturb.schema`): the training config, the simulator's dataset presets, the
conditions of ``generate flight`` and the physics configs are checked by the same code, with the same
words, and overridden with the same ``key=value`` syntax."""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass, field

import pytest
import yaml

from uavturb import cli
from uavturb.cli import main
from uavturb.errors import InputError
from uavturb.io.physics_config import load_physics_config
from uavturb.runs.config import load_config
from uavturb.schema import (
    allowed,
    apply_overrides,
    check_keys,
    option_name,
    parse_overrides,
    read_value,
)
from uavturb.sim.dataset.presets import PRESETS, SimPreset, get_preset, parse_preset_overrides
from uavturb.sim.flights.condition_schema import Conditions, condition_fields


@dataclass(frozen=True)
class Inner:
    rate: float = allowed(1.0, gt=0)


@dataclass(frozen=True)
class Demo:
    count: int = allowed(3, ge=1)
    name: str | None = None
    on: bool = False
    pair: tuple[float, float] | None = allowed(None, length=2)
    table: dict = field(default_factory=lambda: {"a": {"x": 1}, "b": 2})
    inner: Inner = field(default_factory=Inner)


# --- the parser --------------------------------------------------------------------------------


def test_overrides_are_typed_by_the_schema():
    got = parse_overrides(["count=7", "name=null", "on=yes", "pair=1.5,-2", "table.a.y=3", "inner.rate=1e-3",
                           "name=hello world"], Demo)
    assert got == {"count": 7, "name": "hello world", "on": True, "pair": (1.5, -2), "table.a.y": 3,
                   "inner.rate": 1e-3}
    assert type(got["inner.rate"]) is float  # "1e-3" is text to YAML: read as a number by the field
    d = apply_overrides(Demo(), got)
    assert d == Demo(count=7, name="hello world", on=True, pair=(1.5, -2.0),
                     table={"a": {"x": 1, "y": 3}, "b": 2}, inner=Inner(rate=1e-3))  # the rest of table kept
    assert Demo().table == {"a": {"x": 1}, "b": 2}  # the default is not touched
    assert apply_overrides(Demo(), parse_overrides(["table={c: 1}"], Demo)).table == {"c": 1}  # a whole value replaces


@pytest.mark.parametrize("item, where, problem", [
    ("count=abc", "count", "expected an integer, got 'abc'"),
    ("count=2.5", "count", "expected an integer, got '2.5'"),
    ("on=maybe", "on", "expected true or false, got 'maybe'"),
    ("inner.rate=fast", "inner.rate", "expected a number, got 'fast'"),
    ("table=3", "table", "expected a mapping"),
    ("cont=3", "cont", "unknown key (did you mean 'count'?); allowed: count, name, on, pair, table, inner"),
    ("inner.rat=3", "inner.rat", "unknown key (did you mean 'rate'?); allowed: rate"),
    ("count.x=3", "count", "has no keys under it"),
    ("count", "override", "expected KEY=VALUE, got 'count'"),
])
def test_bad_overrides_name_the_key(item, where, problem):
    with pytest.raises(InputError) as e:
        parse_overrides([item], Demo)
    assert e.value.where == where and problem in e.value.problem


def test_every_preset_round_trips_through_the_override_syntax():
    """Each field of a shipped preset written as KEY=VALUE and read back onto the default preset gives it again."""
    for preset in PRESETS.values():
        items = [f"{k}={yaml.safe_dump(v, default_flow_style=True).strip().removesuffix('...').strip()}"
                 for k, v in preset.to_dict().items()]
        assert get_preset(SimPreset(), **parse_preset_overrides(items)) == preset
        assert get_preset(SimPreset(), **parse_preset_overrides(items)).to_dict() == preset.to_dict()


def test_read_value_keeps_an_integer_for_a_float_field():
    """A dataset's config hash is that of what the user wrote (as before the schema): 2 stays 2."""
    assert read_value("2", float, "max_seconds") == 2 and type(read_value("2", float, "max_seconds")) is int
    assert read_value("nan", float, "x") != read_value("nan", float, "x")  # read, then refused by the range check


# --- the same check everywhere ------------------------------------------------------------------


@pytest.mark.parametrize("make, where, value, allowed_text", [
    (lambda: load_config(["trainer.max_epochs=0"]), "trainer.max_epochs", "0", "an integer >= 1"),
    (lambda: load_config(["model.lr_head=-1"]), "model.lr_head", "-1.0", "a number > 0"),
    (lambda: get_preset("tiny", width=0), "preset tiny: width", "0", "an integer >= 1"),
    (lambda: get_preset("quick", yfov_deg=180.0), "preset quick: yfov_deg", "180.0", "a number > 0 and < 180"),
    (lambda: get_preset("tiny", controller="pid"), "preset tiny: controller", "'pid'",
     "one of auto, mpc, geometric"),
    (lambda: get_preset("tiny", plan_points=(0, 1)), "preset tiny: plan_points", "(0, 1)",
     "a non-empty list of integers >= 1"),
    (lambda: Conditions(rate_hz=0.0), "--rate-hz", "0.0",
     "a number > 0 and <= 200 Hz (the simulator records at 200 Hz)"),
    (lambda: Conditions(mass_error=2.0), "--mass-error", "2.0", "a number > -0.5 and < 0.5"),
    (lambda: Conditions(sensor_frame="eurco"), "--sensor-frame", "'eurco'",
     "one of body, euroc (did you mean 'euroc'?)"),
    (lambda: Conditions(wind_speed=(1.0,)), "--wind-speed", "(1.0,)", "two finite numbers vx,vy [m/s]"),
    (lambda: Conditions(heading_deg=float("nan"), fixed_heading=True), "--heading-deg", "nan", "a finite angle [deg]"),
])
def test_out_of_range_values_fail_naming_key_value_and_range(make, where, value, allowed_text):
    """Training config, dataset presets and flight conditions: one message, from uavturb.schema.check_values."""
    with pytest.raises(InputError) as e:
        make()
    assert e.value.where == where
    assert e.value.problem == f"{value} is not allowed; allowed: {allowed_text}"


def test_the_checks_are_the_schemas(monkeypatch):
    """Each settings class's range check is uavturb.schema.check_values (one code path), not its own."""
    import uavturb.runs.config as config
    import uavturb.sim.dataset.presets as presets
    import uavturb.sim.flights.condition_schema as condition_schema

    seen = []

    def spy(obj, *a, **kw):
        seen.append(type(obj).__name__)

    for module in (presets, condition_schema):
        monkeypatch.setattr(module, "check_values", spy)
    monkeypatch.setattr(config.schema, "check_values", spy)
    get_preset("tiny", width=0)  # no longer refused: the range check is the spied one
    Conditions(rate_hz=0.0)
    load_config(["trainer.max_epochs=0"])
    assert seen == ["SimPreset", "Conditions", "DictConfig"]


def test_typos_name_the_closest_key_everywhere(tmp_path):
    with pytest.raises(InputError) as e:
        get_preset("quick", widht=64)
    assert e.value.where == "preset quick: widht" and e.value.problem.startswith("unknown key (did you mean 'width'?)")
    with pytest.raises(InputError) as e:
        parse_preset_overrides(["trajectries=4"], "tiny")
    assert e.value.where == "preset tiny: trajectries" and "(did you mean 'trajectories'?)" in e.value.problem
    with pytest.raises(InputError) as e:
        load_config(["model.use_gr=false"])
    assert e.value.where == "model.use_gr" and "(did you mean 'use_gru'?)" in e.value.problem
    with pytest.raises(InputError) as e:
        Conditions.from_options({"rate_hzz": 50.0})
    assert e.value.where == "--rate-hzz" and "(did you mean 'rate_hz'?)" in e.value.problem
    bad = tmp_path / "physics.yaml"
    bad.write_text(yaml.safe_dump({"effects": {"rotor_drag": {"kd": 1e-4}}}))
    with pytest.raises(InputError) as e:
        load_physics_config(bad)
    assert e.value.where == f"{bad}: effects.rotor_drag.kd" and \
        e.value.problem == "unknown parameter (did you mean 'k_d'?); allowed: k_d"
    with pytest.raises(InputError, match=r"unknown key; allowed: a, b"):
        check_keys(["zzz"], ["a", "b"])


def test_relations_between_fields_stay_with_their_class():
    with pytest.raises(InputError, match="^preset tiny: n_train/n_val/n_test: sum to 4, not n_scenes = 3$"):
        get_preset("tiny", n_train=2)
    with pytest.raises(InputError, match="^--heading-deg: needs --fixed-heading"):
        Conditions(heading_deg=10.0)
    with pytest.raises(InputError, match="^--jitter-ms: must be under half the sampling period \\(10 ms\\)"):
        Conditions(rate_hz=50.0, jitter_ms=10.0)
    assert Conditions(rate_hz=50.0, jitter_ms=9.9).jitter_ms == 9.9


def test_conditions_from_options_reads_text_by_field_type():
    c = Conditions.from_options({"wind_speed": "1,-0.5", "rate_hz": 50.0, "no_imu": True, "sensor_frame": "euroc"})
    assert c == Conditions(wind_speed=(1.0, -0.5), rate_hz=50.0, no_imu=True, sensor_frame="euroc")
    with pytest.raises(InputError,
                       match="^--wind-speed: expected numbers separated by commas \\(or a YAML list\\), got '1,x'$"):
        Conditions.from_options({"wind_speed": "1,x"})


# --- the command line ---------------------------------------------------------------------------


def _subparser(*path: str):
    parser = cli._parser()
    for name in path:
        sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
        parser = sub.choices[name]
    return parser


def test_generate_flight_has_one_option_per_condition_and_no_other():
    """A field added to Conditions without help fails here (and in the parser); one left out of the
    command, or an option that is no field, too."""
    flight = _subparser("generate", "flight")
    group = next(g for g in flight._action_groups if g.title.startswith("real recordings' troubles"))
    fields = condition_fields()
    assert [a.dest for a in group._group_actions] == [f.name for f in fields]
    assert [a.option_strings for a in group._group_actions] == [[option_name(f.name)] for f in fields]
    hints = typing.get_type_hints(Conditions)
    for action, f in zip(group._group_actions, fields):
        assert action.help == f.metadata["help"] and action.default == f.default
        if hints[f.name] is bool:
            assert action.nargs == 0  # a flag
    assert {f.name for f in dataclasses.fields(Conditions)} == {a.dest for a in group._group_actions}
    args = flight.parse_args(["--out", "x", "--rate-hz", "50", "--wind-speed", "1,2", "--no-imu"])
    assert Conditions.from_options({f.name: getattr(args, f.name) for f in fields}) == \
        Conditions(rate_hz=50.0, wind_speed=(1.0, 2.0), no_imu=True)


def test_generate_sim_key_value_and_set_give_the_same_preset(monkeypatch, tmp_path, capsys):
    import uavturb.commands.generate as generate

    got = []
    monkeypatch.setattr(generate, "generate_sim", lambda preset, out, **kw: got.append(
        get_preset(preset, **{k: v for k, v in kw.items() if k not in ("workers", "seed", "shard", "executor",
                                                                          "address")})) or "ok")
    out = str(tmp_path / "d")
    assert main(["generate", "sim", "--preset", "tiny", "--out", out, "width=24", "effects.ground_effect.mu=2.5",
                 "plan_points=[1,2]"]) == 0
    assert main(["generate", "sim", "--preset", "tiny", "--out", out, "--set", "width=24",
                 "--set", "effects.ground_effect.mu=2.5", "--set", "plan_points=[1,2]"]) == 0
    assert main(["generate", "sim", "--out", out, "--preset", "tiny", "--set", "width=24", "plan_points=[1,2]",
                 "effects.ground_effect.mu=2.5"]) == 0
    assert got[0] == got[1] == got[2]
    assert got[0].to_dict() == {**PRESETS["tiny"].to_dict(), "width": 24, "plan_points": [1, 2],
                                "effects": {"ground_effect": {"mu": 2.5}}}


@pytest.mark.parametrize("argv, where", [
    (["width=abc"], "preset tiny: width: expected an integer, got 'abc'"),
    (["--set", "widht=3"], "preset tiny: widht: unknown key (did you mean 'width'?)"),
    (["pairs=0"], "preset tiny: pairs: 0 is not allowed; allowed: an integer >= 1"),
])
def test_generate_sim_bad_overrides_give_one_line(tmp_path, capsys, argv, where):
    out = tmp_path / "d"
    assert main(["generate", "sim", "--preset", "tiny", "--out", str(out), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"uavturb generate: error: {where}")
    assert not out.exists()


def test_sweep_profile_and_its_old_spelling():
    sweep = _subparser("sweep")
    assert sweep.parse_args(["ablation", "--preset", "gpu"]).profile == "gpu"
    assert sweep.parse_args(["ablation", "--profile", "medium"]).profile == "medium"
    assert sweep.parse_args(["ablation"]).profile == "quick"
