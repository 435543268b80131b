"""``uavturb evaluate`` (Table 2) on simulated hexarotor flights where the ground-effect law is
exact, and the recording sequences behind it (camera, frames, GT f_a)."""

from __future__ import annotations

import csv
import dataclasses
import json

import mlflow
import numpy as np
import pytest
import torch
from height_run import tiny_height_run

from uavturb.cli import main
from uavturb.commands.evaluate import evaluate, evaluate_runs
from uavturb.data.recordings import (
    RecordingWindowsDataset,
    box_average,
    cam0_camera,
    recording_sequence,
)
from uavturb.errors import InputError
from uavturb.evaluation.bands import band_edges, band_metrics, ground_effect_height
from uavturb.evaluation.law import evaluation_vehicle, law_consistency
from uavturb.evaluation.metrics import FlightResult, predict_heights
from uavturb.io.reader import read_recording
from uavturb.physics.ground_effect import GroundEffectFit, identify_alpha_beta, phi_alpha_beta
from uavturb.physics.vehicle import HEXAROTOR
from uavturb.sim.flights.sensors import SensorNoise
from uavturb.sim.flights.simulate import generate_flight
from uavturb.runs.store import tracking_uri
from uavturb.scene.camera import forward_camera

MU = 2.0


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """A temporary MLflow store, a tiny trained run and two noise-free hexarotor flights with ground effect."""
    root = tmp_path_factory.mktemp("eval")
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(root)
        mp.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{root / 'mlflow.db'}")
        rid, _, _, module = tiny_height_run(root, use_gru=True, keep="tag", steps=2)
        flights = [generate_flight(vehicle="hex", effects=f"ground_effect:mu={MU}", duration=20, kind="mixed",
                                   seed=s, out=root / f"hex_{s}", noise=SensorNoise.none()).path for s in (0, 1)]
        yield root, rid, module, flights


def test_table2_on_flights_where_the_law_is_exact(setup):
    root, rid, module, flights = setup
    out = root / "table2"
    res = evaluate(rid, flights, out=out, frame_dt=0.1, progress=False)
    rows = dict(res["rows"])
    assert [n for n, _ in res["rows"]] == ["hex_0", "hex_1", "Total"]
    # (alpha, beta) identified by BFGS on the first flight: mu and k_T of the simulator
    assert 16 * res["beta"] / HEXAROTOR.rotor_radius**2 == pytest.approx(MU, rel=0.05)
    assert res["alpha"] / res["beta"] == pytest.approx(HEXAROTOR.thrust_coefficient, rel=0.05)
    assert res["h_ge"] == pytest.approx(ground_effect_height(res["beta"]))
    for name in ("hex_0", "hex_1", "Total"):
        m = rows[name]
        assert m["n_ge"] >= 20 and m["n_all"] > m["n_ge"]
        assert m["rms_fa_gt"] > 0.3  # N: the flights do come close to the ground
        assert m["rmse_fa_phi"] < 0.02 * m["rms_fa_gt"]  # the law is exact: only the frame averaging is left
        assert m["rmse_fa"] > 5 * m["rmse_fa_phi"]  # an untrained network is far worse
    assert rows["Total"]["n_ge"] == rows["hex_0"]["n_ge"] + rows["hex_1"]["n_ge"]

    files = sorted(p.name for p in out.iterdir())
    assert files == [".uavturb-output.json", "evaluation.json", "fa_hex_0.png", "fa_hex_1.png", "series_hex_0.csv",
                     "series_hex_1.csv", "table.csv", "table.md"]
    table = list(csv.DictReader(open(out / "table.csv")))
    assert [r["flight"] for r in table] == ["hex_0", "hex_1", "Total"]
    assert float(table[2]["rmse_fa"]) == pytest.approx(rows["Total"]["rmse_fa"])
    assert (out / "table.md").read_text().count("\n| ") == 4 + 5  # header + 3 rows; bands: header + 4 bands
    # the model's f_a is the identified law on the predicted heights
    s = np.genfromtxt(out / "series_hex_1.csv", delimiter=",", names=True)
    r1 = res["results"][1]
    np.testing.assert_allclose(s["d_hat_m"], r1.d_hat, rtol=1e-5)
    np.testing.assert_allclose(r1.fa_model, phi_alpha_beta(r1.d_hat, _S(flights[1], r1), res["alpha"], res["beta"]),
                               rtol=1e-6)
    # metrics in an MLflow child run of the training run
    child = mlflow.MlflowClient(tracking_uri()).get_run(res["mlflow_run"])
    assert child.data.tags["mlflow.parentRunId"] == rid and child.data.tags["evaluation"] == "table2"
    assert child.data.metrics["eval/rmse_fa_phi"] == pytest.approx(rows["Total"]["rmse_fa_phi"])
    assert not [k for k in child.data.metrics if "hex_" in k]  # per-flight figures: artifacts, not columns
    # the same evaluation again reuses its child run (a second `make demo` adds no run)
    again = evaluate(rid, flights, out=out, frame_dt=0.1, progress=False, overwrite=True)
    assert again["mlflow_run"] == res["mlflow_run"]
    client = mlflow.MlflowClient(tracking_uri())
    children = client.search_runs([child.info.experiment_id], f"tags.`mlflow.parentRunId` = '{rid}'")
    assert [c.info.run_id for c in children] == [res["mlflow_run"]]
    info = json.loads((out / "evaluation.json").read_text())
    assert info["identified_on"] == "hex_0" and "identified on hex_0" in info["vehicle_constants"]
    assert info["law_check"] is None and 0 < info["beta_stderr"] < 0.05 * info["beta"]  # flights at many heights


def _S(flight, result):
    """sum Omega^2 at the frames of ``result``, from the recording (independent of evaluate)."""
    rec = read_recording(flight)
    t = rec.seconds(rec.rotors.t_ns)
    speeds = np.column_stack([np.interp(result.t, t, c) for c in rec.rotors.speeds.T])
    return (speeds**2).sum(1)


def test_heights_carry_the_gru_state_across_chunks(setup):
    _, _, module, _ = setup
    depth = np.random.default_rng(0).uniform(0.5, 4, (23, 16, 16)).astype(np.float32)
    whole = predict_heights(module, depth, chunk=100)
    np.testing.assert_allclose(predict_heights(module, depth, chunk=5), whole, rtol=0, atol=1e-6)
    with torch.no_grad():
        alone = module(torch.from_numpy(depth[5:10])[None, :, None])[0][0].numpy()
    assert np.abs(alone - whole[5:10]).max() > 1e-6  # memory from frames 0-4 matters


def test_recording_sequence_frames_and_ground_truth(setup):
    _, _, _, flights = setup
    rec = read_recording(flights[0])
    seq = recording_sequence(rec, rec.vehicle, forward_camera(16, 16, 70.0, 45.0), frame_dt=0.25)
    assert len(seq) == 81 and np.allclose(np.diff(seq.t), 0.25)
    assert seq.depth.shape == (81, 16, 16) and (seq.depth > 0).mean() > 0.95  # closed room: data everywhere
    # on a level body the pitched-down camera sees the floor: the bottom row's depth grows with height
    assert np.corrcoef(seq.d, seq.depth[:, -1, 8])[0, 1] > 0.9
    assert seq.camera.source.startswith("default forward camera")
    assert seq.airborne.all()  # the simulated vehicle hovers from the start: never resting on the floor
    # GT f_a is the law itself here (noise-free flight, nominal constants = the simulator's)
    law = phi_alpha_beta(seq.d, seq.sum_omega2, HEXAROTOR.thrust_coefficient * MU * 0.01 / 16, MU * 0.01 / 16)
    assert np.sqrt(np.mean((law - seq.fa) ** 2)) < 0.02 * np.sqrt(np.mean(seq.fa**2))
    # as windows for Trainer.test: the keys and shapes of the shard windows
    ds = RecordingWindowsDataset([seq, seq], window=4, stride=2)
    assert len(ds) == 2 * len(range(0, 81 - 4 + 1, 2))
    item = ds[len(ds) - 1]
    assert item["depth"].shape == (4, 1, 16, 16) and item["d"].shape == item["fa"].shape == (4,)
    np.testing.assert_allclose(item["sum_omega2"].numpy(), seq.sum_omega2[76:80], rtol=1e-6)


def test_an_accelerometer_bias_is_not_ground_truth_turbulence(setup):
    """The same flight with its accelerometer reading 0.5 m/s^2 too much along z (0.75 N on this vehicle): the
    ground-truth f_a is unchanged, the bias measured against the motion capture and taken off."""
    _, _, _, flights = setup
    rec = read_recording(flights[0])
    assert rec.imu is not None
    biased = dataclasses.replace(rec, imu=dataclasses.replace(rec.imu, acc=rec.imu.acc + np.array([0.0, 0.0, 0.5])))
    cam = forward_camera(16, 16, 70.0, 45.0)
    fa, fa_biased = (recording_sequence(r, rec.vehicle, cam, frame_dt=0.25).fa for r in (rec, biased))
    assert np.abs(fa_biased - fa).max() < 0.005


def test_commands_through_an_idle_speed_are_read_as_identified(setup):
    """The same noise-free flight with its rotor speeds recorded as commands 30 % of the hover speed under the
    rotors' own (an idle speed in the command map): the vehicle identified on it reads the offset, and every
    flight's ground-truth f_a and sum of squared speeds are read on the speeds so moved. Then f_a is the true one
    again and the law's mu the simulator's; read as recorded, with the same constants, f_a was a third of its size
    off and mu 2.6."""
    _, _, _, flights = setup
    rec = read_recording(flights[0])
    w = rec.rotors.speeds
    idle = 0.3 * float(np.median(w))
    commands = dataclasses.replace(rec, rotors=dataclasses.replace(rec.rotors, speeds=np.where(w > 0, w - idle, 0.0)))
    veh, source, read = evaluation_vehicle(commands, progress=False)
    assert read is not None and "moved by" in source
    cam = forward_camera(16, 16, 70.0, 45.0)
    truth = recording_sequence(rec, rec.vehicle, cam, frame_dt=0.25)
    size = np.sqrt(np.mean(truth.fa**2))

    def fa_error(seq):
        return np.sqrt(np.mean((seq.fa - truth.fa) ** 2)) / size

    def mu(seq):
        fit = identify_alpha_beta(seq.fa[seq.airborne], seq.d[seq.airborne], seq.sum_omega2[seq.airborne])
        return 16 * fit.beta / HEXAROTOR.rotor_radius**2

    as_read = recording_sequence(commands, veh, cam, frame_dt=0.25, speeds_read=read)
    as_recorded = recording_sequence(commands, veh, cam, frame_dt=0.25)
    assert fa_error(as_read) < 0.03 and mu(as_read) == pytest.approx(MU, rel=0.03)
    assert fa_error(as_recorded) > 0.2 and mu(as_recorded) > 1.2 * MU
    # speeds the identification leaves as recorded: no reading, and the sequence is the recorded one
    _, _, read_exact = evaluation_vehicle(rec, progress=False)
    assert read_exact is None


def test_cameras():
    # default camera: the training shards' intrinsics (pixel_rays) and a downward pitch
    cam = forward_camera(32, 32, yfov_deg=70.0, pitch_deg=45.0)
    f = 16 / np.tan(np.deg2rad(35))
    np.testing.assert_allclose(cam.K, [[f, 0, 15.5], [0, f, 15.5], [0, 0, 1]])
    np.testing.assert_allclose(cam.T_BC[:3, 2], [np.sqrt(0.5), 0, -np.sqrt(0.5)], atol=1e-12)  # optical axis in B
    # cam0 crop + scale: a point projects where the original image's centre square, scaled, has it
    from conftest import make_recording

    rec = make_recording()
    small = cam0_camera(rec, 120)
    K = rec.cam0.K
    X = np.array([0.3, -0.2, 2.0])
    u, v = (K @ X)[:2] / X[2]
    us, vs = (small.K @ X)[:2] / X[2]
    side = 480
    x0 = (752 - side) / 2
    assert us == pytest.approx((u + 0.5 - x0) * 120 / side - 0.5)
    assert vs == pytest.approx((v + 0.5) * 120 / side - 0.5)
    np.testing.assert_array_equal(small.T_BC, rec.cam0.T_BS)


def test_grounded_frames_are_left_out():
    d = np.array([0.1, 0.1, 0.2, 2.0, np.inf])
    fa = np.array([5.0, 1.0, 0.5, 0.0, 0.0])
    fa_phi = np.array([-20.0, 1.1, 0.5, 0.0, 0.0])  # frame 0: resting on the floor, contact force in the residual
    airborne = np.array([False, True, True, True, True])
    ge = airborne & (d <= 0.3)
    m = FlightResult("x", np.arange(5.0), d, d, fa, fa_phi, fa_phi, ge, airborne).metrics()
    assert m["n_ge"] == 2 and m["n_all"] == 3
    assert m["rmse_fa_phi"] == pytest.approx(np.sqrt(0.01 / 2)) and m["rmse_fa_phi_all"] == pytest.approx(0.1 / 3**0.5)


def test_height_bands_known_answer():
    """Bands cut at the law's 5 % and 2 % of thrust; per band the law's and the model's errors, the height
    bias and the band's share of the squared f_a error."""
    beta = 1.25e-3
    edges = band_edges(beta, 0.01)
    h20, h5, h2, h1 = (ground_effect_height(beta, f) for f in (0.2, 0.05, 0.02, 0.01))
    assert [(lo, hi) for lo, hi, _ in edges] == [(0.0, h20), (h20, h5), (h5, h2), (h2, h1)]
    assert "law >= 20 % of thrust" in edges[0][2] and "law 1-2 % of thrust" in edges[3][2]
    assert len(band_edges(beta, 0.03)) == 3  # the 2 % band lies outside a 3 % region
    d = np.array([0.15, 0.16, 0.2, 0.3, 1.0])
    d_hat = d + np.array([0.01, -0.01, 0.02, 0.0, 0.5])
    fa = np.array([1.0, 1.0, 0.4, 0.1, 0.0])
    fa_model = fa + np.array([0.3, -0.1, 0.2, 0.0, 0.1])
    ge = d <= h1
    a = FlightResult("a", np.arange(3.0), d[:3], d_hat[:3], fa[:3], fa[:3], fa_model[:3], ge[:3], ge[:3] | True)
    b = FlightResult("b", np.arange(2.0), d[3:], d_hat[3:], fa[3:], fa[3:] + 0.05, fa_model[3:], ge[3:], ge[3:] | True)
    bands = band_metrics([a, b], beta, 0.01)
    assert [x["n"] for x in bands] == [0, 2, 1, 1]  # none under 8.7 cm | 0.15, 0.16 | 0.2 | 0.3; 1 m: outside
    bands = bands[1:]
    assert bands[0]["rmse_fa"] == pytest.approx(np.sqrt((0.09 + 0.01) / 2))
    assert bands[0]["bias_d"] == pytest.approx(0.0) and bands[1]["bias_d"] == pytest.approx(0.02)
    assert bands[2]["rmse_fa_phi"] == pytest.approx(0.05) and bands[2]["rmse_fa"] == 0.0
    assert [x["share_sq_fa"] for x in bands] == pytest.approx([0.1 / 0.14, 0.04 / 0.14, 0.0])


def test_box_average():
    t = np.arange(0, 1, 0.01)
    x = np.where(t < 0.5, 1.0, 3.0)
    np.testing.assert_allclose(box_average(t, x, np.array([0.2, 0.8, 0.5]), 0.1), [1.0, 3.0, 2.0])


def test_evaluate_bad_inputs(setup, tmp_path):
    root, rid, _, flights = setup
    with pytest.raises(InputError, match="no run 'nope'"):
        evaluate("nope", flights, out=tmp_path / "x", progress=False)
    bare = tmp_path / "bare"
    import shutil

    shutil.copytree(flights[0], bare)
    (bare / "mav0/pointcloud0/data.ply").unlink()
    with pytest.raises(InputError, match="pointcloud0") as e:
        evaluate(rid, [bare], out=tmp_path / "y", progress=False, log=False)
    assert e.value.where.endswith("mav0/pointcloud0/data.ply")
    assert not (tmp_path / "y").exists()
    with pytest.raises(InputError, match="not found"):
        evaluate(rid, [tmp_path / "missing"], out=tmp_path / "z", progress=False, log=False)


@pytest.mark.slow
def test_table2_with_realistic_sensor_noise(setup, tmp_path):
    root, rid, _, _ = setup
    flights = [generate_flight(vehicle="hex", effects=f"ground_effect:mu={MU}", duration=20, kind="mixed", seed=s,
                               out=tmp_path / f"noisy_{s}").path for s in (0, 1)]
    res = evaluate(rid, flights, out=tmp_path / "t", frame_dt=0.05, progress=False, log=False)
    for _, m in res["rows"]:
        # 1 mm MoCap noise on heights of ~6 cm, where the law is steep, dominates
        assert m["rmse_fa_phi"] < 0.1 * m["rms_fa_gt"]


def test_table2_over_runs(setup, tmp_path):
    """Several runs on the same flights: per run what ``evaluate`` gives for it alone, summarised per row
    (the runs' name here) over its seeds, with the ratio and the height bands; one folder, published whole."""
    root, rid, _, flights = setup
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(root)
        rid2 = tiny_height_run(root / "second", use_gru=True, keep="tag", steps=4)[0]
    out = tmp_path / "seeds"
    res = evaluate_runs([rid, rid2], flights, out=out, frame_dt=0.1, progress=False)
    alone = evaluate(rid2, flights, out=tmp_path / "alone", frame_dt=0.1, progress=False, log=False)
    assert res["runs"][1]["total"] == pytest.approx(dict(alone["rows"])["Total"])
    (row,) = res["rows"]
    assert row["row"] == "height-none-gru" and row["n"] == 2
    totals = [r["total"] for r in res["runs"]]
    ratios = [t["rmse_fa"] / t["rmse_fa_phi"] for t in totals]
    assert row["ratio"] == pytest.approx(np.mean(ratios)) and row["ratio_std"] == pytest.approx(np.std(ratios, ddof=1))
    assert row["ratio_max"] == pytest.approx(max(ratios))
    assert row["rmse_fa"] == pytest.approx(np.mean([t["rmse_fa"] for t in totals]))
    assert sum(b["n"] for b in row["bands"]) == totals[0]["n_ge"]
    assert sum(b["share_sq_fa"] for b in res["runs"][0]["bands"]) == pytest.approx(1.0)
    files = sorted(p.name for p in out.iterdir())
    assert {"summary.md", "summary.json", "bands.png"} <= set(files) and len([f for f in files if "seed" in f]) == 0
    assert len([p for p in out.iterdir() if p.is_dir()]) == 2
    assert (out / "summary.md").read_text().count("| height-none-gru | 2 |") == 1
    assert all(r["mlflow_run"] for r in res["runs"])
    with pytest.raises(InputError, match="twice"):
        evaluate_runs([rid, rid], flights, out=tmp_path / "twice", progress=False, log=False)
    assert not (tmp_path / "twice").exists()


def test_the_model_carries_its_camera_when_its_data_is_gone(setup, tmp_path):
    """A run trained on data of a camera pitched 20 deg (not the synthetic default 45 deg): its checkpoint
    and its run carry that camera, so Table 2 is the same after the training data is moved away."""
    _, _, _, flights = setup
    rid, ckpt, data, module = tiny_height_run(tmp_path, keep="tag", steps=2, pitch_deg=20.0)
    cam = module.camera_model()
    assert (cam.name, cam.width, cam.height, cam.frame_dt) == ("forward", 16, 16, 0.05)
    np.testing.assert_allclose(cam.T_BC[:3, 2], [np.cos(np.deg2rad(20)), 0, -np.sin(np.deg2rad(20))], atol=1e-12)
    run = mlflow.MlflowClient(tracking_uri()).get_run(rid)
    assert json.loads(run.data.tags["camera"]) == module.hparams["camera"]
    before = evaluate(rid, flights, out=tmp_path / "before", frame_dt=0.1, progress=False, log=False)
    data.rename(tmp_path / "moved")  # another folder, another machine: the run's data.root is not found
    after = evaluate(rid, flights, out=tmp_path / "after", frame_dt=0.1, progress=False, log=False)
    assert after["table"] == before["table"] and after["rows"] == before["rows"]
    info = json.loads((tmp_path / "after" / "evaluation.json").read_text())
    assert info["camera"] == "default forward camera (pitch 20 deg down, vertical fov 70 deg)"
    # the checkpoint alone carries it too (no run: nothing else to read it from)
    alone = evaluate(None, flights, checkpoint=ckpt, out=tmp_path / "alone", frame_dt=0.1, progress=False,
                     log=False)
    assert alone["rows"] == before["rows"]
    # through the 45 deg camera the old fallback assumed, the frames differ: the camera matters here
    rec = read_recording(flights[0])
    ours = recording_sequence(rec, HEXAROTOR, cam, frame_dt=0.1).depth
    assert not np.allclose(ours, recording_sequence(rec, HEXAROTOR, forward_camera(16, 16, 70.0, 45.0),
                                                    frame_dt=0.1).depth, atol=0.05)


def test_a_model_without_a_camera_is_refused_in_one_line(setup, tmp_path, capsys):
    """Trained before models kept their camera: evaluate and export refuse it, naming it; nothing is guessed."""
    _, _, _, flights = setup
    rid, ckpt, _, module = tiny_height_run(tmp_path, keep="tag", steps=1, camera=False)
    assert module.camera_model() is None
    assert main(["evaluate", str(flights[0]), "--run", rid, "--out", str(tmp_path / "a")]) == 2
    assert main(["export", "--run", rid, "--out", str(tmp_path / "b"), "--no-mlflow"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(f"run {rid}: the model carries no camera" in line for line in err)
    with pytest.raises(InputError, match="the model carries no camera") as e:
        evaluate(None, flights, checkpoint=ckpt, out=tmp_path / "c", progress=False, log=False)
    assert e.value.where == str(ckpt)
    assert not any((tmp_path / x).exists() for x in "abc")


def test_evaluate_cli_needs_runs_or_a_sweep(setup, tmp_path, capsys):
    _, rid, _, flights = setup
    assert main(["evaluate", str(flights[0]), "--out", str(tmp_path / "a")]) == 2
    assert main(["evaluate", str(flights[0]), "--run", rid, "--rows", "x", "--out", str(tmp_path / "b")]) == 2
    assert main(["evaluate", str(flights[0]), "--sweep", "nope", "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and "--run" in err[0] and "--rows" in err[1] and "no run 'nope'" in err[2]
    assert not any((tmp_path / x).exists() for x in "abc")


def test_a_law_that_contradicts_the_vehicle_is_flagged():
    """alpha / beta is the thrust coefficient in the paper's form: a fit 4.8 times off (the stand-in
    flights' identification: beta steepened after k_T took the law's far tail) is flagged, one within
    the tolerance is not."""
    k_T = 8.54858e-6
    assert law_consistency(GroundEffectFit(alpha=1.1 * k_T * 1.25e-3, beta=1.25e-3, rmse=0.02, n=100), k_T) is None
    msg = law_consistency(GroundEffectFit(alpha=9.02e-9, beta=5.04e-3, rmse=0.02, n=100), k_T)
    assert msg is not None and "0.21 times the vehicle's" in msg and "not reliable" in msg
