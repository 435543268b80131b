"""How the gap report and `uavturb gap` print their findings for people (formatting only)."""

from __future__ import annotations

from uavturb.gap.finder import height_reference
from uavturb.gap.report import format_effect, format_params, write_markdown
from uavturb.gap.selection import better_law_not_named


def test_effects_print_as_names_and_values_not_dicts():
    e = {"name": "ground_effect", "params": {"mu": 1.999560421719929}, "stderr": {"mu": 0.0021344}}
    assert format_effect(e) == "ground_effect (mu = 1.9996 ± 0.0021)"
    assert format_params({"c_x": 0.5, "c_y": 0.25}) == "c_x = 0.5, c_y = 0.25"
    assert format_params(None) == "-"


def test_report_lists_segments_largest_first_and_params_readably(tmp_path):
    segs = [{"recording": "a/hex_0", "t_start": t, "t_end": t + 1, "axis": "z", "rms_N": rms}
            for t, rms in ((1.0, 0.2), (5.0, 0.9), (9.0, 0.5))]
    report = {"recordings": ["a/hex_0"], "sim_effects": ["ground_effect"], "protocol": "2-fold",
              "residual_source": "imu",
              "baseline": {"heldout_rmse_N": 0.27, "rmse_N": 0.26}, "final": {"heldout_rmse_N": 0.08},
              "noise": {"rms_N": 0.075}, "effects": [],
              "sim_effect_params": {"ground_effect": {"sim": {"mu": 2.0}, "fitted": {"mu": 1.8712345}}},
              "mismatch": {"segments": segs, "drivers": []}, "unexplained": {"rms_N": 0.01, "drivers": []}}
    write_markdown(tmp_path, report, [])
    text = (tmp_path / "report.md").read_text()
    assert "(largest first)" in text
    rows = [line for line in text.splitlines() if line.startswith("| hex_0 |")]
    assert [float(r.split("|")[5]) for r in rows] == [0.9, 0.5, 0.2]
    assert "simulator mu = 2, fitted mu = 1.871" in text and "{" not in text


def test_a_thrust_axis_tilt_prints_per_recording_and_the_drivers_say_they_are_what_it_leaves(tmp_path):
    tilt = {"per_recording": [{"recording": "a/mq_11", "tilt_deg": 1.2012, "stderr_deg": 0.0089, "azimuth_deg": -0.2,
                               "z": 130.0},
                              {"recording": "a/mq_12", "tilt_deg": 0.81, "stderr_deg": 0.012, "azimuth_deg": 89.6,
                               "z": 70.0}],
            "explains_share": 0.93, "rms_beyond_tilt_N": 0.012, "heading_span_deg": 180.0, "why": "it turns"}
    report = {"recordings": ["a/mq_11", "a/mq_12"], "sim_effects": [], "protocol": "leave-one-recording-out",
              "residual_source": "ground_truth", "baseline": {"heldout_rmse_N": 0.49, "rmse_N": 0.49},
              "final": {"heldout_rmse_N": 0.29}, "noise": {"rms_N": 0.13}, "effects": [], "sim_effect_params": {},
              "mismatch": {"segments": [], "drivers": []},
              "unexplained": {"rms_N": 0.21, "drivers": [{"feature": "v_z", "score": 0.08}], "thrust_axis_tilt": tilt}}
    write_markdown(tmp_path, report, [])
    text = (tmp_path / "report.md").read_text()
    assert "drivers of what the thrust-axis tilt below leaves: v_z 0.08" in text
    assert ("Thrust-axis tilt: mq_11 1.20 ± 0.0089 deg towards 0 deg (from body +x to +y); mq_12 0.81 ± 0.012 deg "
            "towards 90 deg (from body +x to +y). It explains 93 % of the horizontal residual (RMS beyond noise left: "
            "0.0120 N): it turns.") in text


def test_late_streams_say_what_is_left_uncertain_of_their_delay(tmp_path):
    delays = [{"recording": "a/px4-0", "describe": "rotors0 (measured rotor speeds) late by 61 ± 4 ms",
               "applied": True, "uncertain_s": [-0.004, 0.004]},
              {"recording": "a/px4-1", "describe": "rotors0 (measured rotor speeds): delay not resolvable",
               "applied": False, "uncertain_s": [0.0, 0.08]}]
    report = {"recordings": ["a/px4-0", "a/px4-1"], "sim_effects": [], "protocol": "leave-one-recording-out",
              "residual_source": "ground_truth", "baseline": {"heldout_rmse_N": 0.27, "rmse_N": 0.26},
              "final": {"heldout_rmse_N": 0.2}, "noise": {"rms_N": 0.075}, "effects": [],
              "mismatch": {"segments": [], "drivers": []}, "unexplained": {"rms_N": 0.01, "drivers": []},
              "sim_effect_params": {}, "streams": {"streams": [], "stream_limits": [], "delays": delays, "dropouts": [
                  {"recording": "a/px4-0", "stream": "mav0/rotors0/data.csv", "t_start": 12.0, "t_end": 15.5},
                  {"recording": "a/px4-0", "stream": "mav0/rotors0/data.csv", "t_start": 40.0, "t_end": 40.25},
                  {"recording": "a/px4-1", "stream": "mav0/imu0/data.csv", "t_start": 3.0, "t_end": 3.5}]}}
    write_markdown(tmp_path, report, [])
    text = (tmp_path / "report.md").read_text()
    assert ("- px4-0: rotors0 (measured rotor speeds) late by 61 ± 4 ms (taken out of the timestamps; the delay "
            "taken out may be off by -4 to +4 ms") in text
    assert "- px4-1: rotors0 (measured rotor speeds): delay not resolvable (not taken out; the true delay may be " \
           "anywhere from 0 to 80 ms" in text
    # dropouts: one line per recording and stream
    assert "- **Dropout**: px4-0/rotors0 has no sample for 2 stretches, 3.75 s in all (the longest 3.50 s " \
           "(12.00-15.50 s)): the rows there" in text
    assert "- **Dropout**: px4-1/imu0 has no sample for 0.50 s (3.00-3.50 s): the rows there" in text


def test_a_law_named_from_the_surface_curve_says_which_law_found_it(tmp_path):
    exp = {"name": "ground_effect_exponential", "params": {"A": 0.411, "lam": 1.66}, "stderr": {"A": 0.11, "lam": 0.19},
           "explanation": "Extra lift ...", "heldout_rmse_before_N": 0.0323, "heldout_rmse_after_N": 0.0229,
           "z_heldout": 7.6, "named_from": "surface_curve",
           "error_budget": {"A": {"sample": 0.037, "height_reference": 0.108, "between_recordings": 0.087,
                                  "stderr": 0.115, "limited_by": "height_reference", "fits": 2,
                                  "recordings_too_short": 1}},
           "time_domain": {"name": "ground_effect", "params": {"mu": 6.217}, "stderr": {"mu": 3.45}}}
    report = {"recordings": ["a/to67"], "sim_effects": [], "protocol": "leave-one-recording-out",
              "residual_source": "imu", "baseline": {"heldout_rmse_N": 0.0323, "rmse_N": 0.0323},
              "final": {"heldout_rmse_N": 0.0201}, "noise": {"rms_N": 0.015}, "effects": [exp],
              "mismatch": {"segments": [], "drivers": []}, "unexplained": {"rms_N": 0.01, "drivers": []},
              "sim_effect_params": {}}
    write_markdown(tmp_path, report, [])
    text = (tmp_path / "report.md").read_text()
    assert "| `ground_effect_exponential` | A = 0.41 ± 0.11, lam = 1.66 ± 0.19 |" in text
    assert "  - named from the measured surface curve; found in time as `ground_effect` (mu = 6.2 ± 3.5)" in text
    assert ("  - error of A: ± 0.115, limited by height reference (sample 0.037, height reference 0.108, between "
            "recordings 0.087); 1 recording(s) with too few rows in flight to be fitted alone left out of the spread "
            "between recordings") in text


def test_a_recording_that_cannot_test_an_effect_is_named_in_its_error_line(tmp_path):
    drag = {"name": "rotor_drag", "params": {"k_d": 1.85e-6}, "stderr": {"k_d": 2.2e-7}, "explanation": "Drag ...",
            "heldout_rmse_before_N": 0.0077, "heldout_rmse_after_N": 0.0075, "z_heldout": 9.5,
            "error_budget": {"k_d": {"sample": 7.8e-8, "between_recordings": 2.06e-7, "stderr": 2.2e-7,
                                     "limited_by": "between_recordings", "fits": 2,
                                     "recordings_cannot_test": ["cf50_00"]}}}
    report = {"recordings": ["a/cf50_00", "a/cf50_01", "a/cf50_02"], "sim_effects": [],
              "protocol": "leave-one-recording-out", "residual_source": "imu",
              "baseline": {"heldout_rmse_N": 0.0117, "rmse_N": 0.0117}, "final": {"heldout_rmse_N": 0.0075},
              "noise": {"rms_N": 0.006}, "effects": [drag], "mismatch": {"segments": [], "drivers": []},
              "unexplained": {"rms_N": 0.01, "drivers": []}, "sim_effect_params": {}}
    write_markdown(tmp_path, report, [])
    assert ("  - error of k_d: ± 2.2e-07, limited by between recordings (sample 7.8e-08, between recordings 2.06e-07); "
            "cf50_00 cannot test it on its own rows (the effect there under 0.2 % of the weight): left out of the "
            "spread between recordings") in (tmp_path / "report.md").read_text()


def test_the_surface_curve_says_where_heights_are_measured_from(tmp_path):
    """The report states the rotor plane's offset behind every height, and where a surface law is named on the
    body origin's heights (rotor_plane_z 0 or absent), says to check it: mu moves 2-3x with it on real vehicles."""
    assert height_reference(-0.025, 0.01, True) == {"rotor_plane_z_m": -0.025, "uncertainty_m": 0.01, "note": None}
    assert height_reference(0.0, 0.01, False)["note"] is None  # no surface law named: nothing rests on it
    note = height_reference(0.0, 0.01, True)["note"]
    assert "rotor_plane_z is 0 or absent" in note and "+-1 cm" in note
    curve = {"far_m": 0.23, "law": "ground_effect", "params": {"mu": 5.1}, "stderr": {"mu": 0.6}, "chi2_dof": 1.2,
             "law_fits": True, "why": "it fits.", "bins": [{"d_m": 0.05, "n": 40, "ratio": 1.08, "stderr": 0.01,
                                                            "law": 1.07}]}
    report = {"recordings": ["a/rw32a"], "sim_effects": [], "protocol": "last-30%-of-each-recording",
              "residual_source": "imu", "baseline": {"heldout_rmse_N": 0.011, "rmse_N": 0.011},
              "final": {"heldout_rmse_N": 0.008}, "noise": {"rms_N": 0.005}, "effects": [],
              "mismatch": {"segments": [], "drivers": []}, "unexplained": {"rms_N": 0.004, "drivers": []},
              "sim_effect_params": {}, "surface_curve": curve, "height_reference": height_reference(-0.025, 0.01, True)}
    write_markdown(tmp_path, report, [])
    text = (tmp_path / "report.md").read_text()
    assert ("by the rotor plane's height (rotor_plane_z: 2.5 cm below the body origin, "
            "+-1 cm in every stated error)" in text)
    assert "Height reference" not in text
    assert "Measured between" not in text and "Not named" not in text  # bins without their edges: no range
    curve["not_named"] = "the curve stands 11 standard errors above 1 near the floor, a lift no law is named for"
    curve["bins"][0] |= {"lo_m": 0.048, "hi_m": 0.053}
    write_markdown(tmp_path, report, [])
    assert ("Measured between 0.048 and 0.053 m (the hover-like samples' rotor-plane heights): the law's values "
            "nearer the floor or farther from it are its shape carried beyond these flights, not a measurement."
            ) in (tmp_path / "report.md").read_text()
    assert ("**Not named**: the curve stands 11 standard errors above 1 near the floor, a lift no law is named for."
            in (tmp_path / "report.md").read_text())
    report["height_reference"] = height_reference(0.0, 0.01, True)
    write_markdown(tmp_path, report, [])
    text = (tmp_path / "report.md").read_text()
    assert ("(rotor_plane_z: the body origin, +-1 cm" in text
            and "**Height reference**: vehicle.yaml's rotor_plane_z" in text)
    # no curve: where the finder says why, the report does; where it says nothing, no section
    report.update(surface_curve=None, surface_curve_missing="recording f0 left out: it hovered above 1.270 m "
                                                            "(far from the surface) in only 3 samples (needs 30)")
    write_markdown(tmp_path, report, [])
    text = (tmp_path / "report.md").read_text()
    assert "## Measured surface curve\nNot measured: recording f0 left out: it hovered above 1.270 m" in text
    report["surface_curve_missing"] = None
    write_markdown(tmp_path, report, [])
    assert "## Measured surface curve" not in (tmp_path / "report.md").read_text()


def test_a_nominal_model_that_misses_by_much_of_the_weight_says_what_to_check(tmp_path):
    report = {"recordings": ["a/px4"], "sim_effects": [], "protocol": "2-fold", "residual_source": "imu",
              "baseline": {"heldout_rmse_N": 7.1, "rmse_N": 5.3}, "final": {"heldout_rmse_N": 7.1},
              "noise": {"rms_N": 0.64}, "effects": [], "sim_effect_params": {},
              "mismatch": {"segments": [], "drivers": []}, "unexplained": {"rms_N": 5.3, "drivers": []},
              "facts": {"weight_N": 14.715}}
    write_markdown(tmp_path, report, [])
    text = (tmp_path / "report.md").read_text()
    assert "(nominal model 5.3000 N on all data, 36 % of the weight;" in text
    assert "**The nominal model misses by 36 % of the weight**" in text and "check vehicle.yaml" in text
    report["baseline"]["rmse_N"] = 0.5  # 3.4 %: as real flights leave
    write_markdown(tmp_path, report, [])
    text = (tmp_path / "report.md").read_text()
    assert "3.4 % of the weight" in text and "misses by" not in text


def test_effects_fitted_but_not_discoveries_say_why_each_is_not(tmp_path):
    report = {"recordings": ["a/hex"], "sim_effects": [], "protocol": "2-fold", "residual_source": "imu",
              "baseline": {"heldout_rmse_N": 0.17, "rmse_N": 0.24}, "final": {"heldout_rmse_N": 0.17},
              "noise": {"rms_N": 0.09}, "effects": [], "sim_effect_params": {},
              "mismatch": {"segments": [], "drivers": []}, "unexplained": {"rms_N": 0.1, "drivers": []},
              "facts": {"weight_N": 14.715},
              "rejected": [{"name": "ground_effect_exponential", "reason": "not_pinned", "why": "its A rests on one "
                            "sample"}, {"name": "body_drag", "reason": "outside_range", "why": "c_d = 0.12 kg/m"},
                           {"name": "wind", "why": "a push of 0.0007 N"}]}
    write_markdown(tmp_path, report, [])
    text = (tmp_path / "report.md").read_text()
    assert ("## Fitted, not discoveries\n- `ground_effect_exponential` (not pinned by these flights): its A rests on "
            "one sample.\n- `body_drag` (outside its physical range): c_d = 0.12 kg/m.\n- `wind`: a push of 0.0007 N."
            ) in text
    assert "Fits outside their physical range" not in text


def test_with_battery_sag_named_k_T_is_said_to_be_the_start_of_the_flight_s(tmp_path):
    sag = {"name": "battery_sag", "params": {"s": 0.0012}, "stderr": {"s": 0.0002}, "explanation": "sags",
           "heldout_rmse_before_N": 0.03, "heldout_rmse_after_N": 0.02, "z_heldout": 6.0}
    report = {"recordings": ["a/cf102_00"], "sim_effects": [], "protocol": "last-30%-of-each-recording",
              "residual_source": "imu", "baseline": {"heldout_rmse_N": 0.03, "rmse_N": 0.03},
              "final": {"heldout_rmse_N": 0.02}, "noise": {"rms_N": 0.01}, "effects": [sag], "sim_effect_params": {},
              "mismatch": {"segments": [], "drivers": []}, "unexplained": {"rms_N": 0.01, "drivers": []},
              "nominal": {"thrust_coefficient": 2.9e-8, "thrust_coefficient_stderr": 1e-10,
                          "thrust_coefficient_stderr_terms": {"sample": 1e-10, "between_recordings": 0.0}}}
    write_markdown(tmp_path, report, [])
    text = (tmp_path / "report.md").read_text()
    assert ("Thrust coefficient k_T = 2.9e-08 ± 1e-10 N/(rad/s)^2 (0.34 %, limited by sample noise). It is the value "
            "at each recording's start: with `battery_sag` named (s = 0.0012 /s) the thrust per rotor speed squared "
            "is k_T (1 - s t)") in text
    report["effects"] = []
    write_markdown(tmp_path, report, [])
    assert "each recording's start" not in (tmp_path / "report.md").read_text()


def test_nothing_named_with_something_undecided_does_not_say_nothing_improves_the_fit(tmp_path):
    """An 8 s flight whose ground effect removed 98 % of the held-out error at z = 0 (too few blocks) had read
    "no effect of the vocabulary improves the held-out fit beyond what noise explains"."""
    undecided = {"candidates": ["ground_effect", "thrust_coefficient"], "why": "ground_effect would take the "
                 "held-out error from 1.938 to 0.04682 N (98 % less), but ...", "to_separate": "longer flights"}
    report = {"recordings": ["a/short"], "sim_effects": [], "protocol": "last-30%-of-each-recording",
              "residual_source": "imu", "baseline": {"heldout_rmse_N": 1.94, "rmse_N": 1.92},
              "final": {"heldout_rmse_N": 1.94}, "noise": {"rms_N": 0.06}, "effects": [], "sim_effect_params": {},
              "mismatch": {"segments": [], "drivers": []}, "unexplained": {"rms_N": 1.9, "drivers": []},
              "ambiguous": [undecided]}
    write_markdown(tmp_path, report, [])
    text = (tmp_path / "report.md").read_text()
    assert "None: what these flights cannot decide is listed under Undecided." in text
    assert "beyond what noise explains" not in text and "98 % less" in text
    report["ambiguous"] = []
    write_markdown(tmp_path, report, [])
    assert "None: no effect of the vocabulary improves the held-out fit beyond what noise explains." in (
        tmp_path / "report.md").read_text()


def test_a_thrust_coefficient_left_undecided_beside_a_surface_law_says_what_limits_it(tmp_path):
    """Two hovers at 0.15 m whose thrust levels differ by 4 % cannot tell a ground effect from the thrust level:
    the law is undecided, and k_T's error covers how far it moves with the law fitted (7.5 %, where the sample
    noise alone gave 0.7 %)."""
    report = {"recordings": ["a/h1", "a/h2"], "sim_effects": [], "protocol": "leave-one-recording-out",
              "residual_source": "imu", "baseline": {"heldout_rmse_N": 1.05, "rmse_N": 1.05},
              "final": {"heldout_rmse_N": 1.05}, "noise": {"rms_N": 0.06}, "effects": [], "sim_effect_params": {},
              "mismatch": {"segments": [], "drivers": []}, "unexplained": {"rms_N": 1.0, "drivers": []},
              "nominal": {"thrust_coefficient": 1.637e-05, "thrust_coefficient_stderr": 1.2e-06,
                          "thrust_coefficient_stderr_terms": {"sample": 1.1e-07, "between_recordings": 4.6e-07,
                                                              "undecided_thrust_law": 1.2e-06}}}
    write_markdown(tmp_path, report, [])
    assert ("Thrust coefficient k_T = 1.637e-05 ± 1.2e-06 N/(rad/s)^2 (7.3 %, limited by the law scaling the thrust "
            "left undecided beside it") in (tmp_path / "report.md").read_text()
    report["nominal"]["thrust_coefficient_stderr_terms"] = {"sample": 1.1e-07, "between_recordings": 4.6e-07}
    report["nominal"]["thrust_coefficient_stderr"] = 4.6e-07
    write_markdown(tmp_path, report, [])
    assert "limited by the spread between recordings" in (tmp_path / "report.md").read_text()


def test_every_candidate_tried_and_not_named_is_said_with_its_gain(tmp_path):
    """A candidate the data did not support is listed with its held-out gain at the last step it was tried at; one
    chosen and dropped by the backward check says so (a 5 s and a 120 s recording had dropped a rotor drag chosen at
    32 errors without a word), one the named effects' errors carry says so; surface laws beside a named one of their
    surface are the measured curve's to compare, and what is named, undecided or untestable is said elsewhere."""
    tried = {"ground_effect": {"step1_z": 300.0}, "ground_effect_exponential": {"step1_z": 8.0},
             "rotor_drag": {"step1_z": 32.0, "dropped_z": 0.86, "step2_curve_lift_z": 5.0},
             "body_drag": {"step1_z": 0.5, "step2_z": 1.9}, "wind": {"step1_z": -0.5}, "motor_lag": {"step1_z": 0.1}}
    report = {"recordings": ["a/x"], "sim_effects": [], "protocol": "leave-one-recording-out",
              "residual_source": "imu", "baseline": {"heldout_rmse_N": 0.27, "rmse_N": 0.26},
              "final": {"heldout_rmse_N": 0.2}, "noise": {"rms_N": 0.075}, "mismatch": {"segments": [], "drivers": []},
              "unexplained": {"rms_N": 0.01, "drivers": []}, "sim_effect_params": {},
              "effects": [{"name": "ground_effect", "params": {"mu": 2.0}, "stderr": {"mu": 0.5},
                           "heldout_rmse_before_N": 0.27, "heldout_rmse_after_N": 0.2, "z_heldout": 300.0,
                           "explanation": "lift", "untaken_candidates": {"body_drag": 1.9}}],
              "not_testable": [{"name": "motor_lag", "why": "no steps", "to_separate": "steps"}],
              "candidates_tried": tried}
    write_markdown(tmp_path, report, [])
    text = (tmp_path / "report.md").read_text()
    section = text.split("## Tried, not named")[1].split("\n## ")[0]
    lines = [line for line in section.splitlines() if line.startswith("- ")]
    assert [line.split("`")[1] for line in lines] == ["rotor_drag", "body_drag", "wind"]
    assert ("held-out gain 32 errors at step 1 (4 needed); chosen, then dropped: without it the held-out fit was "
            "worse by only 0.86 errors") in lines[0]
    assert "held-out gain 1.9 errors at step 2" in lines[1] and "it is in their errors (untaken candidate)" in lines[1]
    assert lines[2].endswith("To show it: fly the same pattern at two or more headings and speeds.")


def _one_effect_report(effect: dict, **more) -> dict:
    return {"recordings": ["a/q1"], "sim_effects": [], "protocol": "last-30%-of-each-recording",
            "residual_source": "mocap", "baseline": {"heldout_rmse_N": 0.52, "rmse_N": 0.52},
            "final": {"heldout_rmse_N": 0.17}, "noise": {"rms_N": 0.08}, "effects": [effect],
            "mismatch": {"segments": [], "drivers": []}, "unexplained": {"rms_N": 0.1, "drivers": []},
            "sim_effect_params": {}} | more


def test_a_better_law_left_unnamed_without_a_curve_is_said(tmp_path):
    """No measured curve judged the shapes, and the exponential law fitted the held-out rows better than the one
    named, by too little to be named instead: the report says the law is not decided, by how much, and what to fly;
    the selection's record gives the last comparison, and none where the alternative lost or would have won."""
    tried = {"ground_effect_exponential": {"step1_z_over_ground_effect": 3.55},
             "ground_effect_multirotor": {"step1_z_over_ground_effect": -0.4}}
    assert better_law_not_named("ground_effect", tried) == ("ground_effect_exponential", 3.55)
    assert better_law_not_named("ground_effect", {"ground_effect_exponential": {
        "step1_z_over_ground_effect": 3.0, "step2_z_over_ground_effect": -0.5}}) is None  # its last comparison lost
    assert better_law_not_named("ground_effect", {"ground_effect_exponential": {
        "step1_z_over_ground_effect": 4.5}}) is None  # beyond Z_IMPROVE it would have been named (the shape decided)
    ge = {"name": "ground_effect", "params": {"mu": 5.15}, "stderr": {"mu": 0.69}, "explanation": "Extra lift ...",
          "heldout_rmse_before_N": 0.52, "heldout_rmse_after_N": 0.17, "z_heldout": 11.4,
          "law_shape_open": {"law": "ground_effect_exponential", "heldout_z_over": 1.21, "needed": 2.0}}
    write_markdown(tmp_path, _one_effect_report(ge), [])  # without a curve, 2 errors would have named it instead
    assert ("  - its law is not decided: `ground_effect_exponential` fitted the held-out rows better, by 1.2 errors "
            "(2 needed to name it instead), and no measured surface curve judged their shapes"
            ) in (tmp_path / "report.md").read_text()
    ge["law_shape_open"] |= {"heldout_z_over": 2.6, "not_pinned_by_heights": True}  # over the bar, not pinned
    write_markdown(tmp_path, _one_effect_report(ge), [])
    assert ("by 2.6 errors (2 needed to name it instead, but its parameter moves by more than half its value with "
            "the heights moved by the height reference's +-1 cm)") in (tmp_path / "report.md").read_text()
    ge["law_shape_open"] = {"law": None, "heldout_z_over": None, "needed": 4.0}  # no better law: the shape unchecked
    write_markdown(tmp_path, _one_effect_report(ge), [])
    text = (tmp_path / "report.md").read_text()
    assert "  - its shape was not checked: no surface curve was measured, so" in text and "not decided" not in text


def test_a_curve_on_commanded_speeds_with_an_open_offset_says_how_far_it_moves(tmp_path):
    curve = {"far_m": 0.12, "law": "ground_effect", "params": {"mu": 2.6}, "stderr": {"mu": 0.42}, "chi2_dof": 0.7,
             "law_fits": True, "why": "it fits.", "thrust_map": {"mu": 0.42},
             "bins": [{"d_m": 0.05, "n": 40, "ratio": 1.12, "stderr": 0.01, "law": 1.12, "stderr_thrust_map": 0.051},
                      {"d_m": 0.09, "n": 40, "ratio": 1.03, "stderr": 0.01, "law": 1.03, "stderr_thrust_map": 0.02}]}
    ge = {"name": "ground_effect", "params": {"mu": 2.6}, "stderr": {"mu": 2.7}, "explanation": "Extra lift ...",
          "heldout_rmse_before_N": 0.0083, "heldout_rmse_after_N": 0.0006, "z_heldout": 30.0}
    write_markdown(tmp_path, _one_effect_report(ge, surface_curve=curve), [])
    assert ("across the offsets left open each bin's ratio moves by up to ± 0.051 beside its ± above, and the law's "
            "values on the curve by mu ± 0.42 (in their stated errors)") in (tmp_path / "report.md").read_text()


def test_the_law_band_says_whether_the_named_law_is_known_to_two_percent(tmp_path):
    ge = {"name": "ground_effect", "params": {"mu": 6.3}, "stderr": {"mu": 3.1}, "explanation": "Extra lift ...",
          "heldout_rmse_before_N": 0.0115, "heldout_rmse_after_N": 0.007, "z_heldout": 5.9}
    bins = [{"d_m": 0.051, "n": 30, "ratio": 1.0846, "stderr": 0.0062, "law": 1.0899, "law_stderr": 0.0483},
            {"d_m": 0.087, "n": 48, "ratio": 1.0329, "stderr": 0.0176, "law": 1.0405, "law_stderr": 0.0211}]
    curve = {"far_m": 0.23, "law": "ground_effect", "params": {"mu": 6.0}, "stderr": {"mu": 0.62}, "chi2_dof": 0.09,
             "law_fits": True, "why": "it fits.", "bins": bins,
             "named": {"law": "ground_effect", "params": {"mu": 6.3}, "largest_band": 0.0483}}
    write_markdown(tmp_path, _one_effect_report(ge, surface_curve=curve), [])
    text = (tmp_path / "report.md").read_text()
    assert "| rotor-plane height [m] | samples | measured ratio | ± | law | law ± |" in text
    assert "| 0.051 | 30 | 1.0846 | 0.0062 | 1.0899 | 0.0483 |" in text
    assert ("up to 4.8 % of thrust: beyond 2 % these flights do not pin the law down at every height." in text
            and "Each parameter is moved alone" not in text)
    curve["named"]["largest_band"] = 0.015
    write_markdown(tmp_path, _one_effect_report(ge, surface_curve=curve), [])
    assert "up to 1.5 % of thrust: it is known to within 2 % in every bin." in (tmp_path / "report.md").read_text()
    curve["named"]["law"] = "ground_effect_exponential"  # two parameters, each moved alone: said
    write_markdown(tmp_path, _one_effect_report(ge, surface_curve=curve), [])
    assert ("Each parameter is moved alone: where they trade against each other, together they move the law less."
            in (tmp_path / "report.md").read_text())
    for b in bins:
        del b["law_stderr"]
    write_markdown(tmp_path, _one_effect_report(ge, surface_curve=curve), [])
    text = (tmp_path / "report.md").read_text()
    assert "law ± |" not in text and "Law ±" not in text  # no band: the table as before


def test_a_state_too_slow_for_a_surface_effect_says_when_one_was_named_all_the_same(tmp_path):
    """The ground truth updating at 9 Hz is too slow for a surface effect; where one was named anyway, its error
    carrying the stream-rate term, the line says so rather than leave the two looking at odds."""
    slow = ("a_q/state_groundtruth_estimate0 updates at 9.0 Hz (82 % of its rows repeat the last value): too slow "
            "for a surface effect (heights crossed in 0.2 s), which needs updates at 10 Hz or faster")
    ge = {"name": "ground_effect", "params": {"mu": 2.03}, "stderr": {"mu": 0.28}, "explanation": "Extra lift ...",
          "heldout_rmse_before_N": 0.5, "heldout_rmse_after_N": 0.08, "z_heldout": 12.0,
          "error_budget": {"mu": {"sample": 0.05, "stream_rate": 0.1, "stderr": 0.28, "limited_by": "sample"}}}
    report = _one_effect_report(ge, streams={"streams": [], "stream_limits": [slow], "delays": [], "dropouts": []})
    write_markdown(tmp_path, report, [])
    assert (f"- **Too slow**: {slow}; `ground_effect` named all the same, its error carrying what thinning these "
            "updates to every other one changes (stream rate)") in (tmp_path / "report.md").read_text()
    del ge["error_budget"]["mu"]["stream_rate"]
    write_markdown(tmp_path, report, [])
    assert f"- **Too slow**: {slow}\n" in (tmp_path / "report.md").read_text()


def test_a_ground_law_not_named_on_flights_that_hovered_near_the_floor_asks_for_more_of_them_not_for_the_hovers(
        tmp_path):
    """A probe's ladders of 1.5-8 rotor radii with ESC speeds at 3 Hz had been told to "hover over the floor at
    several heights"; flights that came near it are told what the held-out rows lacked, and of the slow stream."""
    base = {"recordings": ["a/lad"], "sim_effects": [], "protocol": "last-30%-of-each-recording",
            "residual_source": "ground_truth", "baseline": {"heldout_rmse_N": 0.46, "rmse_N": 0.46},
            "final": {"heldout_rmse_N": 0.46}, "noise": {"rms_N": 0.37}, "effects": [], "sim_effect_params": {},
            "mismatch": {"segments": [], "drivers": []}, "unexplained": {"rms_N": 0.0, "drivers": []},
            "candidates_tried": {"ground_effect": {"step1_z": 0.27}, "rotor_drag": {"step1_z": -0.3}},
            "streams": {"streams": [], "slowest_update_hz": 3.1}}
    for near, said in ((0.17, "To show it: these flights came within 0.17 m of the floor; what the held-out rows "
                              "(last-30%-of-each-recording) hold near it was too little to test it: longer hovers near "
                              "it, or more recordings, or a faster stream than the slowest here (3.1 Hz updates)."),
                       (1.4, "To show it: hover over the floor at several heights within a few rotor radii.")):
        write_markdown(tmp_path, base | {"facts": {"d_down_min_m": near}}, [])
        text = (tmp_path / "report.md").read_text()
        assert said in text
        assert "`rotor_drag`: held-out gain -0.3 errors at step 1 (4 needed). To show it: fly at several" in text


def test_a_motor_lag_not_named_says_what_the_torques_time(tmp_path):
    """A gentle flight's thrust cannot show a 30 ms motor lag on its held-out rows (z 1.3), but its roll and pitch
    torques time it (facts.torque_lag, decisive): the line under Tried, not named says so."""
    report = _one_effect_report({"name": "ground_effect", "params": {"mu": 3.0}, "stderr": {"mu": 1.0},
                                 "heldout_rmse_before_N": 0.5, "heldout_rmse_after_N": 0.2, "z_heldout": 9.0,
                                 "explanation": "lift"},
                                candidates_tried={"motor_lag": {"step1_z": 1.3}},
                                facts={"torque_lag": {"tau_s": 0.0304, "stderr_s": 0.0025, "decisive": True,
                                                      "correlation": 0.99, "correlation_at_zero": 0.97, "rows": 6000}},
                                streams={"streams": ["a/q1/rotors0: 8001 rows"]})
    write_markdown(tmp_path, report, [])
    text = (tmp_path / "report.md").read_text()
    (line,) = [x for x in text.splitlines() if x.startswith("- `motor_lag`: held-out gain 1.3")]
    assert "the roll and pitch torques lag the commands by 30 ± 2 ms" in line or "by 30 ± 3 ms" in line
    assert "- **Commanded rotor speeds**: the roll and pitch torques line up" in text and "the motors' own lag" in text
    report["facts"]["torque_lag"]["decisive"] = False
    write_markdown(tmp_path, report, [])
    text = (tmp_path / "report.md").read_text()
    assert "torques lag the commands" not in text and "no lag the torques can tell from none" in text


def test_an_alternative_law_better_by_less_than_the_rounding_is_said_beside_the_standard_law(tmp_path):
    """Rotor speeds rounded to their resolution: the exponential law fitted the held-out rows better than
    Cheeseman-Bennett by 4.4 errors, but its gain in mean squared error lay under what the rounding can fake, so the
    standard law is named (selection's ``_standard_law``) and the report says why, once, with the margin."""
    import numpy as np

    from uavturb.gap.selection import CurveEvidence, HeldOut, _standard_law

    rng = np.random.default_rng(3)
    resid = rng.normal(0.0, 1.0e-3, size=(4000, 3))
    t, group = np.arange(4000) * 0.01, np.zeros(4000, int)  # s: 40 s of held-out rows at 100 Hz
    standard = HeldOut(resid * 1.08, np.arange(4000) // 100, t, group)  # Cheeseman-Bennett's held-out residuals
    better = HeldOut(resid, np.arange(4000) // 100, t, group)  # the exponential law's, 8 % smaller
    passed = {"ground_effect": ("ground_effect", standard, 9.0),
              "ground_effect_exponential": ("ground_effect_exponential", better, 11.0)}
    gain = float(np.mean(standard.err2) - np.mean(better.err2))  # N^2
    for floor, named in ((0.0, "ground_effect_exponential"), (0.5 * gain, "ground_effect_exponential"),
                         (2.0 * gain, "ground_effect")):
        tried = {"ground_effect_exponential": {}}
        chosen = _standard_law(passed["ground_effect_exponential"], passed, 4.0, tried, 2, CurveEvidence(),
                               thrust_floor=floor)
        assert chosen[0] == named
        assert ("step2_over_ground_effect_below_rounding_floor" in tried["ground_effect_exponential"]) == (
            named == "ground_effect")
    report = _one_effect_report({"name": "ground_effect", "params": {"mu": 1.86}, "stderr": {"mu": 1.7},
                                 "explanation": "lift", "heldout_rmse_before_N": 0.0032,
                                 "heldout_rmse_after_N": 0.0013, "z_heldout": 8.7},
                                candidates_tried={"ground_effect_exponential": tried["ground_effect_exponential"]
                                                  | {"step2_z": 11.5}})
    write_markdown(tmp_path, report, [])
    text = (tmp_path / "report.md").read_text()
    z = tried["ground_effect_exponential"]["step2_z_over_ground_effect"]
    assert (f"- `ground_effect_exponential`: fitted the held-out rows better than `ground_effect` by {z:.2g} errors at "
            "step 2, but by less than the rotor speeds' rounding can fake along the thrust") in text
    assert text.count("`ground_effect_exponential`") == 1


def test_a_standard_law_named_for_its_alternative_says_so_with_both_held_out_errors(tmp_path):
    """A standard law named where only an alternative of it passed (selection's ``Step.named_for``): the report's
    entry names that law, the gain with which it passed and both held-out errors at that step, and the explanation
    says why the standard law is named. A law standing for itself gets neither."""
    from types import SimpleNamespace

    from uavturb.gap.named_errors import _for_its_physics, _named_for

    tried = {"ground_effect": {"step1_z": 3.36, "step1_heldout_rmse_N": 0.3699,
                               "step1_named_for_ground_effect_multirotor": 4.47},
             "ground_effect_multirotor": {"step1_z": 4.47, "step1_heldout_rmse_N": 0.3739}}
    step = SimpleNamespace(name="ground_effect", named_for="ground_effect_multirotor", z=3.36, named_with=None)
    assert _named_for(step, tried) == {"law": "ground_effect_multirotor", "z_heldout": 4.47,
                                       "heldout_rmse_N": 0.3739, "own_heldout_rmse_N": 0.3699}
    text = _for_its_physics(step.z, _named_for(step, tried))
    assert text == (" Named for its physics: alone this law improved the held-out fit by z = 3.4, while "
                    "ground_effect_multirotor, another law of the same effect, passed with z = 4.5 but fitted the "
                    "held-out rows no better (0.3739 against 0.3699 N): another law is named instead only where it "
                    "fits better.")
    assert _for_its_physics(6.0, None) == ""
    # report.md's table gives both gains: the law's own, and the one it was named for
    report = _one_effect_report({"name": "ground_effect", "params": {"mu": 4.29}, "stderr": {"mu": 0.58},
                                 "explanation": "lift." + text, "heldout_rmse_before_N": 0.5323,
                                 "heldout_rmse_after_N": 0.3699, "z_heldout": 3.36,
                                 "named_for": _named_for(step, tried)})
    write_markdown(tmp_path, report, [])
    md = (tmp_path / "report.md").read_text()
    assert "| `ground_effect` | mu = 4.29 ± 0.58 | 0.5323 → 0.3699 | 3.4 (4.5 for `ground_effect_multirotor`) |" in md


def test_a_standard_law_named_for_its_alternative_beside_a_partner_says_both():
    """The same for two laws named together (a surface law and the battery's sag): the held-out errors are the
    pairs', the sentences say the gain was with the partner, and the partner's sentence does not claim that its pair
    passed by itself."""
    from types import SimpleNamespace

    from uavturb.gap.named_errors import _for_its_physics, _named_for, _together

    tried = {"ground_effect": {"step1_z": -2.0, "step1_heldout_rmse_N": 0.61, "step1_z_with_battery_sag": 2.8,
                               "step1_heldout_rmse_with_battery_sag_N": 0.152,
                               "step1_named_for_ground_effect_multirotor": 4.6},
             "ground_effect_multirotor": {"step1_z": -1.0, "step1_heldout_rmse_N": 0.60,
                                          "step1_z_with_battery_sag": 4.6,
                                          "step1_heldout_rmse_with_battery_sag_N": 0.301}}
    law = SimpleNamespace(name="ground_effect", named_for="ground_effect_multirotor", z=2.8, named_with="battery_sag")
    sag = SimpleNamespace(name="battery_sag", named_for=None, z=2.8, named_with="ground_effect")
    f = _named_for(law, tried)
    assert f == {"law": "ground_effect_multirotor", "z_heldout": 4.6, "heldout_rmse_N": 0.301,
                 "own_heldout_rmse_N": 0.152, "with": "battery_sag"}
    assert _for_its_physics(law.z, f) == (
        " Named for its physics: beside battery_sag this law improved the held-out fit by z = 2.8, while "
        "ground_effect_multirotor, another law of the same effect, passed beside battery_sag with z = 4.6 but fitted "
        "the held-out rows no better (0.301 against 0.152 N): another law is named instead only where it fits better.")
    for step, other in ((law, sag), (sag, law)):
        text = _together(step, [law, sag])
        assert "together they do" not in text and "together they gain z = 2.8" in text, text
        assert "ground_effect_multirotor in the place of ground_effect passed with the other" in text
    plain = SimpleNamespace(name="battery_sag", named_for=None, z=6.1, named_with="ground_effect")
    partner = SimpleNamespace(name="ground_effect", named_for=None, z=6.1, named_with="battery_sag")
    assert _together(plain, [partner, plain]).endswith("together they do (z = 6.1).")
    assert _together(plain, [plain]) == ""  # its partner no longer named
