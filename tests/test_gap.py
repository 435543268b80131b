"""The gap finder on flights with known, concealed effects (gap-report.md contract)."""

import io
import json
import shutil
import tempfile
from pathlib import Path

import mlflow
import numpy as np
import pytest

from uavturb.errors import InputError
from uavturb.commands.gap import gap
from uavturb.gap import finder
from uavturb.gap import report as gap_report
from uavturb.gap.finder import analyse, parse_sim_effects
from uavturb.io.reader import load_recordings
from uavturb.numerics import processes
from uavturb.io.physics_config import load_physics_config
from uavturb.physics.effects import DEFAULT_EFFECTS
from uavturb.sim.flights.condition_schema import Conditions
from uavturb.sim.flights.conditions import generate_conditioned_flight
from uavturb.sim.flights.simulate import generate_flight

REQUIRED = {"schema", "recordings", "sim_effects", "protocol", "baseline", "mismatch", "effects",
            "sim_effect_params", "final", "unexplained"}


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    root = tmp_path_factory.mktemp("gapflights")
    made = {}
    for name, effects, seed in [("clean", "none", 11), ("drag", "rotor_drag:k_d=8.06e-5", 12),
                                ("ground", "ground_effect:mu=2.0", 13), ("ground2", "ground_effect:mu=2.0", 14)]:
        path = root / name
        generate_flight(vehicle="hex", effects=effects, duration=45.0, kind="mixed", seed=seed, out=path)
        made[name] = path
    return made


def run(tmp_path, recs, **kw):
    out = tmp_path / "report"
    report = gap([str(r) for r in recs], out, log_mlflow=False, **kw)
    on_disk = json.loads((out / "report.json").read_text())
    assert REQUIRED <= set(on_disk)
    assert (out / "report.md").exists()
    assert on_disk["recordings"] == [str(r) for r in recs]
    for seg in on_disk["mismatch"]["segments"]:  # gap-report.md: path, seconds since the first ground-truth row
        assert seg["recording"] in on_disk["recordings"]
        assert 0.0 <= seg["t_start"] < seg["t_end"] <= 45.0 + 1e-6
        assert seg["axis"] in ("x", "y", "z") and seg["rms_N"] > 0
    assert all({"feature", "score"} <= set(d) for d in on_disk["mismatch"]["drivers"])
    for e in on_disk["effects"]:
        assert set(e["params"]) == set(e["stderr"])
        assert {"name", "explanation", "heldout_rmse_before_N", "heldout_rmse_after_N"} <= set(e)
    for png in ("residual_time.png", "residual_vs_driver.png", "heldout_fit.png"):
        assert png in (out / "report.md").read_text() and (out / png).stat().st_size > 10_000
    return report


def test_clean_flight_names_nothing(tmp_path, flights):
    report = run(tmp_path, [flights["clean"]], sim_effects="none")
    assert report["effects"] == []
    assert report["protocol"] == "last-30%-of-each-recording"
    assert report["schema"] == "uavturb.gap/1"
    # commanded speeds that are the rotors' own: read far from the floor, no offset stands out
    offset = report["nominal"]["rotor_speed_offset"]
    assert offset["rows"] > 500 and not offset["counts"] and abs(offset["delta_rad_s"]) < 2 * offset["stderr_rad_s"]
    assert "Thrust map: at each height (" in (tmp_path / "report" / "report.md").read_text()


def test_the_gap_run_is_logged_to_mlflow_with_the_report(tmp_path, flights, module_mlflow_store):
    out = tmp_path / "report"
    report = gap([str(flights["drag"])], out, sim_effects="none")  # logged from a second process
    client = mlflow.MlflowClient(module_mlflow_store)
    runs = client.search_runs([client.get_experiment_by_name("uavturb-gap").experiment_id])
    assert len(runs) == 1
    run = runs[0]
    assert run.data.metrics["gap/final_heldout_rmse_N"] == pytest.approx(report["final"]["heldout_rmse_N"])
    assert run.data.tags["effects"] == ",".join(e["name"] for e in report["effects"])
    assert "report.json" in {a.path for a in client.list_artifacts(run.info.run_id)}


def test_rotor_drag_is_named_and_fitted(tmp_path, flights):
    report = run(tmp_path, [flights["drag"]], sim_effects="none")
    assert [e["name"] for e in report["effects"]] == ["rotor_drag"]
    e = report["effects"][0]
    assert e["params"]["k_d"] == pytest.approx(8.06e-5, rel=0.15)
    assert e["heldout_rmse_after_N"] < e["heldout_rmse_before_N"]
    assert report["final"]["heldout_rmse_N"] < report["baseline"]["heldout_rmse_N"]
    assert any(d["feature"] in ("v_Bx", "v_By", "v_x", "v_y", "speed") for d in report["mismatch"]["drivers"])


def test_ground_effect_named_with_two_recordings_and_applied(tmp_path, flights):
    # two flights of the same vehicle in the same room share its physics (a clean flight beside a
    # ground-effect one, both low over the floor, would contradict each other when held out)
    conf = tmp_path / "physics.yaml"
    report = run(tmp_path, [flights["ground"], flights["ground2"]], sim_effects="none", apply=conf)
    assert report["protocol"] == "leave-one-recording-out"
    names = [e["name"] for e in report["effects"]]
    assert "ground_effect" in names
    mu = report["effects"][names.index("ground_effect")]["params"]["mu"]
    assert mu == pytest.approx(2.0, rel=0.15)
    assert report["mismatch"]["drivers"][0]["feature"] == "d_down"
    # the largest located segment is the take-off over the floor, on z; the simulator's vehicle waits still
    # at its lowest height with the thrust under the weight before it (the ground effect itself): nothing shows
    # the floor carrying it (no idling rotors, no thrust moving while it stays still), so it hovers there
    top = report["mismatch"]["segments"][0]
    contact = [c for c in report["ground_contact"] if c["t_start"] < 1.0]
    assert top["axis"] == "z" and top["t_start"] < (contact[0]["t_end"] + 1.0 if contact else 1.0)
    cfg = load_physics_config(conf)
    assert cfg["effects"]["ground_effect"]["mu"] == pytest.approx(mu)
    assert report["open_loop"]["after_m"] <= report["open_loop"]["before_m"]


def test_simulator_effects_are_refitted_not_named(tmp_path, flights):
    report = run(tmp_path, [flights["ground"]], sim_effects="ground_effect")
    assert "ground_effect" not in [e["name"] for e in report["effects"]]
    p = report["sim_effect_params"]["ground_effect"]
    assert p["sim"] == DEFAULT_EFFECTS["ground_effect"]
    assert p["fitted"]["mu"] == pytest.approx(2.0, rel=0.15)


def test_a_simulator_law_that_needs_the_rotor_spacing_is_refitted(tmp_path):
    """``--sim-effects ground_effect_multirotor`` on a flight in that law (K_b = 1.5): the law reads the
    recording's arm length (it used to stop at "needs 'arm_length'", in the simulator's ground contact
    and in the finder), is refitted to its true K_b and not named again."""
    path = tmp_path / "multirotor"
    generate_conditioned_flight(vehicle="hex", effects="ground_effect_multirotor:K_b=1.5", duration=45.0,
                                kind="low_passes", seed=13, out=path, conditions=Conditions(ground_contact_s=1.0))
    report = run(tmp_path, [path], sim_effects="ground_effect_multirotor")
    assert report["sim_effect_params"]["ground_effect_multirotor"]["sim"] == {"K_b": 1.0}
    assert report["sim_effect_params"]["ground_effect_multirotor"]["fitted"]["K_b"] == pytest.approx(1.5, rel=0.2)
    assert not {"ground_effect", "ground_effect_exponential"} & {e["name"] for e in report["effects"]}
    assert report["ground_contact"]


def test_malformed_recording_writes_no_report(tmp_path, flights):
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(flights["clean"], bad)
    csv = bad / "mav0" / "rotors0" / "data.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join([lines[0]] + [",".join(l.split(",")[:-1]) for l in lines[1:]]) + "\n")
    out = tmp_path / "report"
    with pytest.raises(InputError, match="rotors0"):
        gap([str(bad)], out, log_mlflow=False)
    assert not out.exists()
    assert not any(p.name.startswith(".report") for p in tmp_path.iterdir())


def test_unknown_sim_effect_is_one_clear_error(tmp_path, flights):
    with pytest.raises(InputError, match="--sim-effects.*unknown effect 'gust'"):
        gap([str(flights["clean"])], tmp_path / "r", sim_effects="gust", log_mlflow=False)


def test_simulator_effect_absent_in_reality_is_fitted_to_zero(tmp_path, flights):
    # default --sim-effects: the simulator models ground_effect (mu = 2), the drag flight has none.
    # Its mu must go to 0 (not stay at a search bound, which let a look-alike be named before)
    report = run(tmp_path, [flights["drag"]])
    assert report["sim_effects"] == ["ground_effect"]
    assert [e["name"] for e in report["effects"]] == ["rotor_drag"]
    assert report["sim_effect_params"]["ground_effect"]["fitted"]["mu"] < 0.2
    assert report["final"]["heldout_rmse_N"] < report["baseline"]["heldout_rmse_N"]


def test_a_height_that_passes_through_the_floor_tests_no_surface_effect(tmp_path, flights):
    # a barometer's drift, as in a PX4 log whose local position reads 0.42 m under its take-off floor at
    # touch-down: the ground-effect flight (near the floor for 6 s, then at 1.25 m) sinks 1.6 m from 12 s to
    # 42 s, so that it ends up under the floor
    rec = tmp_path / "drifting"
    shutil.copytree(flights["ground"], rec)
    state = rec / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    header, rows = state.read_text().split("\n", 1)
    table = np.loadtxt(io.StringIO(rows), delimiter=",")
    t = (table[:, 0] - table[0, 0]) * 1e-9
    table[:, 3] -= 1.6 * np.clip((t - 12.0) / 30.0, 0.0, 1.0)
    with state.open("w") as f:
        f.write(header + "\n")
        np.savetxt(f, table, delimiter=",", fmt=["%d"] + ["%.9g"] * (table.shape[1] - 1))
    report = run(tmp_path, [rec], sim_effects="none")
    assert not [e for e in report["effects"] if e["name"].startswith("ground_effect")]
    untestable = {e["name"]: e for e in report["not_testable"]}
    assert ({"ground_effect", "ground_effect_multirotor", "ground_effect_exponential", "ceiling_effect"}
            <= set(untestable))
    assert "cannot be trusted" in untestable["ground_effect"]["why"]
    assert report["surface_curve"] is None
    broken = report["height_reference"]["passes_floor"]
    assert broken == report["surface_curve_missing"] and "drifting: in flight the rotor plane is up to" in broken
    assert "passes through the floor" in (tmp_path / "report" / "report.md").read_text()
    # the same flight without the drift: its height holds
    assert run(tmp_path / "held", [flights["ground"]], sim_effects="none")["height_reference"]["passes_floor"] is None


def test_the_figures_drawn_side_by_side_are_the_plain_loops_pixels(tmp_path, flights, monkeypatch):
    """``write_plots`` draws the report's figures in forked processes: the same files to the byte as drawn one
    after the other here, in the report's order; a figure a child could not draw is drawn here, and its error
    raised here."""
    recs = load_recordings([str(flights["ground"])])
    report, ex = analyse(recs, parse_sim_effects("none"))
    args = (ex["data"], ex["r0"], ex["rs0"], ex["rf"], ex["rsf"], ex["segs"], "d_down", ex["base_ho"], ex["final_ho"])
    surface = (ex["curve"], ex["curve_fits"], ex.get("curve_named"))
    assert report["surface_curve"] is not None
    (tmp_path / "forked").mkdir()
    (tmp_path / "plain").mkdir()
    names = gap_report.write_plots(tmp_path / "forked", *args, surface=surface)
    monkeypatch.setattr(processes, "forking_possible", lambda: False)
    assert gap_report.write_plots(tmp_path / "plain", *args, surface=surface) == names == [
        "residual_time.png", "residual_vs_driver.png", "heldout_fit.png", "surface_curve.png"]
    for name in names:
        assert (tmp_path / "forked" / name).read_bytes() == (tmp_path / "plain" / name).read_bytes()
    monkeypatch.undo()

    def broken(*a, **k):
        raise RuntimeError("this figure cannot be drawn")

    monkeypatch.setattr(gap_report, "plot_heldout_fit", broken)
    with pytest.raises(RuntimeError, match="cannot be drawn"):
        gap_report.write_plots(tmp_path / "forked", *args, surface=surface)


def test_the_figures_drawn_at_the_checkpoint_are_those_drawn_at_the_end(tmp_path, flights, monkeypatch):
    """``analyse`` hands ``at_checkpoint`` the very objects its extras hold, once; the figures a child draws from
    them meanwhile (``FiguresAhead``) are the files ``write_plots`` draws alone, to the byte. Figures started from
    other objects, or a child that fails, leave them to ``write_plots``, and the child's folder is removed."""
    recs = load_recordings([str(flights["ground"])])
    seen = []
    with gap_report.FiguresAhead() as ahead:
        def at_checkpoint(plots):
            seen.append(plots)
            ahead.start(plots)

        report, ex = analyse(recs, parse_sim_effects("none"), at_checkpoint=at_checkpoint)
        assert len(seen) == 1 and all(seen[0][k] is ex[k] for k in seen[0])
        args = (ex["data"], ex["r0"], ex["rs0"], ex["rf"], ex["rsf"], ex["segs"], "d_down", ex["base_ho"],
                ex["final_ho"])
        surface = (ex["curve"], ex["curve_fits"], ex.get("curve_named"))
        child_folder = ahead.folder
        (tmp_path / "ahead").mkdir()
        names = gap_report.write_plots(tmp_path / "ahead", *args, surface=surface, ahead=ahead)
    assert child_folder.parent == Path(tempfile.gettempdir()) and not child_folder.exists()
    (tmp_path / "plain").mkdir()
    assert gap_report.write_plots(tmp_path / "plain", *args, surface=surface) == names
    assert sorted(p.name for p in (tmp_path / "ahead").iterdir()) == sorted(names)
    for name in names:
        assert (tmp_path / "ahead" / name).read_bytes() == (tmp_path / "plain" / name).read_bytes()

    # started from other objects (a guess that missed): not taken, drawn from these
    with gap_report.FiguresAhead() as other:
        other.start(seen[0] | {"rsf": ex["rsf"] * 0.0})
        assert other.drawing(dict(seen[0])) == () and other.folder is None
        (tmp_path / "other").mkdir()
        gap_report.write_plots(tmp_path / "other", *args, surface=surface, ahead=other)
    assert (tmp_path / "other" / "residual_time.png").read_bytes() == (tmp_path / "plain" /
                                                                       "residual_time.png").read_bytes()

    # a child that fails: its figures drawn here
    def broken(*a, **k):
        raise RuntimeError("this figure cannot be drawn in the child")

    monkeypatch.setattr(gap_report, "plot_residual_time", broken)
    with gap_report.FiguresAhead() as failing:
        failing.start(seen[0])
        assert failing.drawing(dict(seen[0])) == gap_report.FiguresAhead.NAMES
        assert failing.taken(tmp_path) == {}
    monkeypatch.undo()


def test_rotor_columns_in_another_order_are_said_and_change_no_force(tmp_path):
    """A log whose rotors0 columns come in another order than vehicle.yaml's angles (two columns swapped): the report
    says which order the torques follow and the fix, reads no torque timing on them, and names the same effects with
    the same values (the thrust is a sum over the rotors); the flight as written reads vehicle.yaml's order. (A
    quadrotor: the simulated hexarotor's controller moves its rotors in pairs alike, which the flight does not tell
    apart.)"""
    written = tmp_path / "quad"
    generate_flight(vehicle="quad", effects="ground_effect:mu=2.0", duration=30.0, kind="mixed", seed=13, out=written)
    swapped = tmp_path / "swapped"
    shutil.copytree(written, swapped)
    csv = swapped / "mav0" / "rotors0" / "data.csv"
    header, *rows = csv.read_text().splitlines()
    cells = [r.split(",") for r in rows]
    csv.write_text("\n".join([header] + [",".join([c[0], c[2], c[1], *c[3:]]) for c in cells]) + "\n")
    as_written = run(tmp_path / "written", [written], sim_effects="none")
    report = run(tmp_path / "swapped_report", [swapped], sim_effects="none")
    assert as_written["facts"]["rotor_order"]["verdict"] == "vehicle.yaml's"
    order = report["facts"]["rotor_order"]
    assert order["verdict"] == "another" and order["best_other"][:2] == [1, 0]
    assert "torque_lag" not in report["facts"]
    said = [line for line in report["streams"]["streams"] if "rotors0: the rotor columns are in another order" in line]
    assert len(said) == 1 and "rotor_angles_deg and rotor_directions in the order of rotors0's columns" in said[0]
    assert said[0] in (tmp_path / "swapped_report" / "report" / "report.md").read_text()
    assert [(e["name"], e["params"]) for e in report["effects"]] == [(e["name"], e["params"])
                                                                     for e in as_written["effects"]]


def test_an_analysis_that_fails_after_its_checkpoint_leaves_no_figure_behind(tmp_path, flights, monkeypatch):
    """The figures started at the checkpoint are the command's own: where the analysis then fails, the child is
    stopped and its folder removed, and the report folder is not written."""
    folders = []
    start = gap_report.FiguresAhead.start

    def started(self, plots):
        start(self, plots)
        folders.append(self.folder)

    def fails(steps):
        raise InputError("rec/mav0/rotors0/data.csv", "fails after the checkpoint")

    monkeypatch.setattr(gap_report.FiguresAhead, "start", started)
    monkeypatch.setattr(finder, "_finished", fails)
    with pytest.raises(InputError, match="fails after the checkpoint"):
        gap([str(flights["ground"])], tmp_path / "report", log_mlflow=False, sim_effects="none")
    assert len(folders) == 1 and folders[0] is not None and not folders[0].exists()
    assert not (tmp_path / "report").exists()
