"""Ground contact on synthetic take-offs and landings with known contact times."""

from __future__ import annotations

import numpy as np
import pytest

from uavturb.errors import InputError
from uavturb.physics.dynamics import GRAVITY
from uavturb.gap.preparation import _vehicle_landed_height
from uavturb.sysid.contact import ContactLimits, _joined_why, ground_contact, landed_height
from uavturb.numerics.stream_updates import update_mask

MASS = 1.5  # kg
Z_LAND = 0.013  # m, height of the body origin when resting on the gear


def _smootherstep(tau):
    """Position, velocity and acceleration shapes of a move with zero speed and acceleration at both ends."""
    s = tau**3 * (10 - 15 * tau + 6 * tau**2)
    ds = 30 * tau**2 * (1 - tau) ** 2
    dds = 60 * tau * (1 - tau) * (1 - 2 * tau)
    return s, ds, dds


def flight(phases, *, rate=100.0, seed=0, z_noise=0.001, floor=0.0):
    """A vertical flight from ``phases``; returns (t, z, v, tilt_deg, thrust, contact truth, floor height).

    Phases: ``("ground", seconds, thrust ratio at start, at end)`` resting on the gear;
    ``("move", seconds, dz)`` a smooth climb (or descent) of ``dz`` m; ``("hover", seconds)``;
    ``("floor", height)`` the surface under the vehicle from here on (a table: ``z`` rests higher).
    In the air the thrust is exactly ``m (g + z'')``; on the ground the ratio given.
    """
    rng = np.random.default_rng(seed)
    cols = {k: [] for k in ("z", "v", "a", "ratio", "contact", "floor")}
    z = Z_LAND + floor
    for ph in phases:
        if ph[0] == "floor":
            floor = ph[1]
            continue
        n = int(round(ph[1] * rate))
        tau = np.arange(n) / n
        zz, vz, az, ratio = np.full(n, z), np.zeros(n), np.zeros(n), np.full(n, np.nan)
        if ph[0] == "ground":
            ratio = ph[2] + (ph[3] - ph[2]) * tau
        elif ph[0] == "move":
            s, ds, dds = _smootherstep(tau)
            zz, vz, az = z + ph[2] * s, ph[2] * ds / ph[1], ph[2] * dds / ph[1] ** 2
            z += ph[2]
        for key, val in zip(cols, (zz, vz, az, ratio, np.full(n, ph[0] == "ground"), np.full(n, floor))):
            cols[key].append(val)
    c = {k: np.concatenate(v) for k, v in cols.items()}
    k = len(c["z"])
    t = np.arange(k) / rate
    air = ~c["contact"]
    thrust = np.where(air, MASS * (GRAVITY + c["a"]), c["ratio"] * MASS * GRAVITY)
    tilt = np.abs(np.where(air, 1.0, 0.5) + rng.normal(0, 0.2, k))  # deg
    v = np.column_stack([rng.normal(0, 0.005, (k, 2)), c["v"] + rng.normal(0, 0.005, k)])
    return t, c["z"] + rng.normal(0, z_noise, k), v, tilt, thrust, c["contact"], c["floor"]


def truth_intervals(t, contact, margin=0.2):
    d = np.diff(np.r_[0, contact.astype(int), 0])
    return [(t[a] - margin, t[b - 1] + margin) for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1))]


def assert_matches(intervals, t, contact, tol=0.3):
    truth = truth_intervals(t, contact)
    got = [(c.t_start, c.t_end) for c in intervals]
    assert len(got) == len(truth), (got, truth)
    for (a, b), (ta, tb) in zip(got, truth):
        assert abs(a - max(ta, t[0])) < tol and abs(b - min(tb, t[-1])) < tol, (got, truth)


TAKEOFF_LANDING = [("ground", 3.0, 0.6, 0.6), ("ground", 0.67, 0.6, 1.0), ("move", 2.0, 0.3), ("hover", 4.0),
                   ("move", 2.0, -0.3), ("ground", 0.5, 1.0, 0.6), ("ground", 2.0, 0.6, 0.6)]


def sample_and_hold(t, arrays, rate_hz, seed=1):
    """Arrays as a logger writes them: updated at ``rate_hz`` (jittered), repeated in between."""
    rng = np.random.default_rng(seed)
    upd = np.cumsum(rng.uniform(0.8, 1.2, int(t[-1] * rate_hz) + 2) / rate_hz)
    rows = np.unique(np.searchsorted(t, upd[upd < t[-1]]))
    is_u = np.zeros(len(t), bool)
    is_u[np.r_[0, rows]] = True
    held = np.maximum.accumulate(np.where(is_u, np.arange(len(t)), 0))
    return [a[held] for a in arrays]


def test_takeoff_and_landing_give_two_intervals_at_the_true_times():
    t, z, v, tilt, thrust, contact, _ = flight(TAKEOFF_LANDING)
    mask, found = ground_contact(t, z, v, tilt, thrust, MASS)
    assert_matches(found, t, contact)
    # the fit keeps the hover and the climb, leaves out every row of true contact
    assert mask[contact].all()
    assert not mask[(t > 5.0) & (t < 10.0)].any()
    assert found[0].t_start == 0.0 and found[1].t_end == t[-1]
    assert found[0].why.startswith("on the landing gear: height 0.0")
    assert "thrust 6" in found[0].why and "% of the weight" in found[0].why
    entry = found[1].to_report("flights/takeoff")
    assert entry == {"recording": "flights/takeoff", "t_start": round(found[1].t_start, 3), "t_end": round(t[-1], 3),
                     "why": found[1].why}


def test_a_low_hover_at_the_landed_height_plus_25_mm_is_in_the_air():
    phases = [("ground", 3.0, 0.6, 0.6), ("ground", 0.67, 0.6, 1.0), ("move", 1.5, 0.025), ("hover", 5.0),
              ("move", 1.5, 0.3), ("hover", 2.0), ("move", 2.0, -0.325), ("ground", 0.5, 1.0, 0.6),
              ("ground", 2.0, 0.6, 0.6)]
    t, z, v, tilt, thrust, contact, _ = flight(phases, seed=3)
    low_hover = (t > 5.2) & (t < 10.1)
    for k_T_error in (1.0, 0.8, 1.2):  # the thrust guessed 20 % low or high
        mask, found = ground_contact(t, z, v, tilt, thrust * k_T_error, MASS)
        assert_matches(found, t, contact)
        assert not mask[low_hover].any()


def test_a_low_hover_is_not_contact_even_where_the_thrust_reads_low_and_is_taken_as_given():
    """Ground effect: the rotors' modelled thrust reads 80 % of the weight in a hover 25 mm up."""
    phases = [("ground", 2.0, 0.6, 0.6), ("ground", 0.67, 0.6, 1.0), ("move", 1.5, 0.025), ("hover", 5.0)]
    t, z, v, tilt, thrust, contact, _ = flight(phases, seed=4)
    mask, found = ground_contact(t, z, v, tilt, 0.8 * thrust, MASS, calibrate=False)
    # the thrust never reads the weight, so only the height tells the lift-off: the slow climb
    # (3 cm/s at most) counts as resting until it is 1.5 cm up, about 0.8 s after lift-off
    assert len(found) == 1 and 2.67 + 0.2 < found[0].t_end < 2.67 + 0.2 + 1.0
    assert not mask[t > 4.0].any()


def test_a_recording_that_never_lands_gives_no_interval():
    t, z, v, tilt, thrust, _, _ = flight([("hover", 3.0), ("move", 2.0, 0.4), ("hover", 5.0), ("move", 2.0, -0.3)])
    z = z + 0.5  # flies 0.5 m and more above anything
    mask, found = ground_contact(t, z, v, tilt, thrust, MASS)
    assert found == [] and not mask.any()
    # a steady hover alone, its thrust read 20 % low and taken as given: only d_down can tell
    t, z, v, tilt, thrust, _, _ = flight([("hover", 10.0)], seed=8)
    z = z + 0.6
    _, by_z = ground_contact(t, z, v, tilt, 0.8 * thrust, MASS, calibrate=False)
    assert len(by_z) == 1  # the lowest height it reached looks like a landed height
    _, by_d_down = ground_contact(t, z, v, tilt, 0.8 * thrust, MASS, d_down=z + 0.05, calibrate=False)
    assert by_d_down == []


def test_touch_and_go_in_the_middle_is_caught():
    phases = TAKEOFF_LANDING[:4] + [("move", 2.0, -0.3), ("ground", 1.5, 0.7, 0.7), ("ground", 0.4, 0.7, 1.0),
                                    ("move", 2.0, 0.3), ("hover", 2.0)] + TAKEOFF_LANDING[4:]
    t, z, v, tilt, thrust, contact, _ = flight(phases, seed=5)
    mask, found = ground_contact(t, z, v, tilt, thrust, MASS)
    assert len(found) == 3
    assert_matches(found, t, contact)


def test_noise_and_held_rows_do_not_break_it():
    """State updated at 9 Hz in 50 Hz rows, thrust from rotor speeds updated at 3 Hz, z noise 1 mm."""
    t, z, v, tilt, thrust, contact, _ = flight(TAKEOFF_LANDING, rate=50.0, seed=6)
    z_h, v_h, tilt_h = sample_and_hold(t, [z, v, tilt], 9.0)
    (thrust_h,) = sample_and_hold(t, [thrust], 3.0, seed=2)
    assert np.mean(np.diff(z_h) == 0) > 0.75
    mask, found = ground_contact(t, z_h, v_h, tilt_h, thrust_h, MASS)
    assert_matches(found, t, contact)


def test_held_positions_do_not_make_a_slow_climb_look_still():
    """A climb at 4 cm/s logged at 5 Hz in 50 Hz rows, velocity differenced from the logged rows:
    zero on the repeats, so over all rows the vehicle looks still; on its updates it moves."""
    t = np.arange(0, 6, 0.02)
    (z,) = sample_and_hold(t, [Z_LAND + np.where(t < 2, 0.0, 0.04 * (t - 2))], 5.0)  # sits 2 s, then climbs
    v = np.column_stack([np.zeros_like(t), np.zeros_like(t), np.gradient(z, t)])
    assert np.median(np.abs(v[t > 2.5, 2])) == 0.0
    thrust = np.where(t < 2, 0.6, 0.9) * MASS * GRAVITY  # reads low: only stillness can tell
    limits = ContactLimits(still_mps=0.03, height_tol_m=0.1, margin_s=0.0)
    args = (t, z, v, np.full_like(t, 0.5), thrust, MASS)
    mask, found = ground_contact(*args, update=update_mask(z), calibrate=False, limits=limits)
    assert len(found) == 1 and found[0].t_end < 2.4
    assert not mask[t > 2.5].any()
    every_row, _ = ground_contact(*args, update=np.ones(len(t), bool), calibrate=False, limits=limits)
    assert every_row[(t > 2.5) & (t < 3.5)].all()  # the failure the updates avoid


def test_rotor_plane_heights_find_a_landing_on_a_table():
    """d_down tells a landing on a 0.5 m table, which the body height alone cannot."""
    phases = TAKEOFF_LANDING[:4] + [("move", 2.0, 0.3), ("floor", 0.5), ("hover", 2.0), ("move", 2.0, -0.1)]
    phases += TAKEOFF_LANDING[5:]
    t, z, v, tilt, thrust, contact, floor = flight(phases, seed=7)
    d_down = z - floor + 0.05  # rotor plane 5 cm above the body origin
    mask, found = ground_contact(t, z, v, tilt, thrust, MASS, d_down=d_down)
    assert_matches(found, t, contact)
    assert "rotor-plane height" in found[1].why
    _, by_z = ground_contact(t, z, v, tilt, thrust, MASS)
    assert len(by_z) == 1


def test_recordings_are_judged_apart():
    t, z, v, tilt, thrust, contact, _ = flight(TAKEOFF_LANDING)
    t2, z2, v2, tilt2, thrust2, _, _ = flight([("hover", 6.0)], seed=2)
    cat = [np.concatenate(p) for p in ((t, t2), (z, z2 + 1.0), (v, v2), (tilt, tilt2), (thrust, thrust2))]
    group = np.r_[np.zeros(len(t), int), np.ones(len(t2), int)]
    mask, found = ground_contact(*cat, MASS, group=group)
    assert [c.group for c in found] == [0, 0]
    assert_matches(found, t, contact)
    assert not mask[group == 1].any()


def test_a_landed_height_given_is_used():
    t, z, v, tilt, thrust, contact, _ = flight(TAKEOFF_LANDING)
    _, found = ground_contact(t, z, v, tilt, thrust, MASS, landed_height=Z_LAND)
    assert_matches(found, t, contact)
    assert "the landed height given, 0.013 m" in found[0].why
    _, none = ground_contact(t, z, v, tilt, thrust, MASS, landed_height=Z_LAND - 0.05)
    assert none == []


def test_rows_of_other_lengths_are_refused():
    t, z, v, tilt, thrust, _, _ = flight(TAKEOFF_LANDING)
    with pytest.raises(InputError, match="thrust"):
        ground_contact(t, z, v, tilt, thrust[:-1], MASS)


def test_a_short_rest_with_the_rotors_off_is_contact():
    """A drop to the floor with the motors off, 0.18 s still, then a restart at 110 % of the weight (the
    thrust read off commanded speeds leads the real one while they spin up): shorter than ``min_s``, but
    rotors off hold no hover. The zero thrust is a state, not a held value: it is not interpolated into
    the restart."""
    phases = [("hover", 2.0), ("move", 1.0, -0.3), ("ground", 0.18, 0.0, 0.0), ("ground", 0.15, 1.1, 1.1),
              ("move", 1.0, 0.3), ("hover", 2.0)]
    t, z, v, tilt, thrust, contact, _ = flight(phases, seed=9, floor=0.3)
    mask, found = ground_contact(t, z, v, tilt, thrust, MASS, calibrate=False)
    assert len(found) == 1
    rest = t[contact]
    assert found[0].t_start <= rest[0] and found[0].t_end >= rest[0] + 0.18
    assert mask[contact].all() and not mask[t < 1.5].any()
    assert "thrust 0 % of the weight" in found[0].why
    # the same rest with the rotors at 80 % of the weight, 0.18 s long: too short to tell from a low hover
    phases[2] = ("ground", 0.18, 0.8, 0.8)
    t, z, v, tilt, thrust, contact, _ = flight(phases, seed=9, floor=0.3)
    _, found = ground_contact(t, z, v, tilt, thrust, MASS, calibrate=False)
    assert found == []


def skid(seed=10, low=0.0):
    """Hover 0.3 m up, come down to ``low`` m over the landed height and slide 0.6 s along the floor at
    0.1 m/s with the thrust at 88 % of the weight (the gear touches), climb back and hover; the
    recording ends on the ground so that its landed height is known."""
    phases = [("hover", 2.0), ("move", 1.5, -0.3 + low), ("hover", 0.6), ("move", 1.5, 0.3 - low), ("hover", 2.0),
              ("move", 2.0, -0.3), ("ground", 2.0, 0.6, 0.6)]
    t, z, v, tilt, thrust, contact, _ = flight(phases, seed=seed, floor=0.3)
    sliding = (t >= 3.5) & (t < 4.1)
    v[sliding, 0] = 0.1
    thrust[sliding] = 0.88 * MASS * GRAVITY
    return t, z, v, tilt, thrust, contact, sliding


def test_a_skid_along_the_floor_is_left_out_but_a_low_hover_of_another_recording_is_not():
    t, z, v, tilt, thrust, contact, sliding = skid()
    mask, found = ground_contact(t, z, v, tilt, thrust, MASS, calibrate=False)
    assert mask[sliding].all() and mask[contact].all()
    assert any(c.why.startswith("skimming the floor") for c in found)
    assert not mask[(t > 5.8) & (t < 7.5)].any()  # the hover between
    # the same manoeuvre 2 cm higher, in a recording whose vehicle landed at the height of the first:
    # it never came within skim_m of the floor, so its low hover is in the air
    t2, z2, v2, tilt2, thrust2, _, sliding2 = skid(seed=11, low=0.02)
    skim_top = float(np.min(z[contact])) + ContactLimits().skim_m
    mask2, found2 = ground_contact(t2, z2, v2, tilt2, thrust2, MASS, calibrate=False, skim_top=skim_top)
    assert not mask2[sliding2].any()
    assert not any(c.why.startswith("skimming the floor") for c in found2)


def test_heights_under_the_vehicles_landed_height_are_no_skim():
    """A recording whose heights run 5 cm under the landed height another recording gave the vehicle (its height
    reference differs: a gear holds the rotor plane up at that height) skims nothing there, however its thrust dips:
    a hover of the probe's at 0.059 m had been left out as "within 0.5 cm of" a landed height of 0.160 m."""
    t, z, v, tilt, thrust, contact, _ = skid()
    skim_top = float(np.min(z[contact])) + ContactLimits().skim_m
    t2, z2, v2, tilt2, thrust2, _, sliding2 = skid(seed=11)
    mask2, found2 = ground_contact(t2, z2 - 0.05, v2, tilt2, thrust2, MASS, calibrate=False, skim_top=skim_top)
    assert sliding2.any() and not mask2[sliding2].any()
    assert not any(c.why.startswith("skimming the floor") for c in found2)
    mask3, _ = ground_contact(t2, z2 - 0.003, v2, tilt2, thrust2, MASS, calibrate=False, skim_top=skim_top)
    assert mask3[sliding2].all()  # within the gear's give under it: still a skim


def _hover_lift_cheeseman_bennett(mu=12.0, r=0.1):
    """The lift a Cheeseman-Bennett ground effect at ``mu`` gives at rotor-plane heights ``h`` [m]."""
    return lambda h: 1.0 / (1.0 - mu * (r / (4.0 * np.asarray(h))) ** 2)


# a hover 1 cm over the landed height, in a ground effect that needs only 93 % of the weight there
HOVER_1CM = [("ground", 3.0, 0.5, 0.5), ("ground", 0.67, 0.5, 1.0), ("move", 0.4, 0.01), ("hover", 3.6),
             ("move", 1.0, 0.3), ("hover", 2.0), ("move", 2.0, -0.31), ("ground", 0.5, 1.0, 0.5),
             ("ground", 2.0, 0.5, 0.5)]


def _hover_1cm(hover_ratio, seed=11):
    t, z, v, tilt, thrust, contact, floor = flight(HOVER_1CM, seed=seed, z_noise=0.0005)
    d_down = z - floor + 0.15  # rotor plane 15 cm above the body origin, landed at 0.163 m
    near = (d_down < 0.163 + 0.015) & ~contact & (t > 3.0) & (t < 10.0)
    thrust = np.where(near & (np.abs(v[:, 2]) < 0.02), hover_ratio * MASS * GRAVITY, thrust)
    thrust = thrust * (1.0 + np.random.default_rng(seed).normal(0.0, 0.002, len(t)))  # not a held stream
    return t, z, v, tilt, thrust, contact, d_down, (t > 5.0) & (t < 7.5)


def test_a_hover_a_centimetre_up_in_ground_effect_is_in_the_air_where_the_lift_could_hold_it():
    """Strongest lift at 0.173 m (mu 12, r 0.1 m): 1.33, so a hover needs only 75 % of the weight there; one at
    93 % is a hover (found as contact without ``hover_lift``), one at 60 % cannot be and is a rest."""
    t, z, v, tilt, thrust, contact, d_down, hover = _hover_1cm(0.93)
    mask, found = ground_contact(t, z, v, tilt, thrust, MASS, d_down=d_down, calibrate=False,
                                 hover_lift=_hover_lift_cheeseman_bennett())
    assert_matches(found, t, contact)
    assert not mask[hover].any()
    old, _ = ground_contact(t, z, v, tilt, thrust, MASS, d_down=d_down, calibrate=False)
    assert old[hover].all()  # the rule without the lift counted that hover as a rest
    t, z, v, tilt, thrust, contact, d_down, hover = _hover_1cm(0.60)
    mask, found = ground_contact(t, z, v, tilt, thrust, MASS, d_down=d_down, calibrate=False,
                                 hover_lift=_hover_lift_cheeseman_bennett())
    assert mask[hover].all()
    assert "stayed under the 75 % that could hold a hover there" in " ".join(f.why for f in found)


def test_a_still_stretch_within_the_gears_reach_is_a_rest_whatever_the_lift():
    """Within ``skim_m`` (5 mm) of the landed height the gear may touch: a still stretch 2 mm up is left out
    even where a ground effect could hold it."""
    phases = [(p[0], p[1], 0.002) if p[0] == "move" and p[2] == 0.01 else p for p in HOVER_1CM]
    phases = [(p[0], p[1], -0.302) if p[0] == "move" and p[2] == -0.31 else p for p in phases]
    t, z, v, tilt, thrust, contact, floor = flight(phases, seed=12, z_noise=0.0005)
    d_down = z - floor + 0.15
    low = (t > 5.0) & (t < 7.5)
    thrust = np.where(low, 0.93 * MASS * GRAVITY, thrust) * (1.0 + np.random.default_rng(12).normal(0.0, 0.002, len(t)))
    mask, _ = ground_contact(t, z, v, tilt, thrust, MASS, d_down=d_down, calibrate=False,
                             hover_lift=_hover_lift_cheeseman_bennett())
    assert mask[low].all()


def test_idling_rotors_rest_wherever_a_drifting_height_reads_them_but_a_motor_cut_in_the_air_does_not():
    # a barometer that reads the first rest 0.4 m over the landing: the height criterion misses it, the idle rotors
    # (0.1 of the weight, 3 s, still and level) tell it
    phases = [("ground", 3.0, 0.1, 0.1), ("ground", 0.67, 0.6, 1.0), ("move", 2.0, 0.3), ("hover", 4.0),
              ("move", 2.0, -0.3), ("ground", 0.5, 1.0, 0.6), ("ground", 2.0, 0.6, 0.6)]
    t, z, v, tilt, thrust, contact, _ = flight(phases, seed=5)
    z = z + np.interp(t, [0.0, 3.0, t[-1]], [0.4, 0.4, 0.0])  # the height sinks 0.4 m from the first rest on;
    # the velocity (motion capture's, or an estimator's) does not drift. Idling rotor speeds jitter (a value that
    # never changes reads as held, and is interpolated between its updates)
    thrust = thrust * (1.0 + np.random.default_rng(7).normal(0.0, 0.002, len(t)))
    mask, found = ground_contact(t, z, v, tilt, thrust, MASS)
    assert found[0].t_start == 0.0 and found[0].t_end == pytest.approx(3.0 + 0.2, abs=0.3)
    assert "the height drifts, but rotors idling under 30 % of the weight hold no still vehicle" in found[0].why
    assert mask[(t < 3.0)].all() and not mask[(t > 5.0) & (t < 10.0)].any()
    # commands cut 5 cm over the floor: still for 0.25 s while the rotors spin down, then the fall: no rest
    cut = [("ground", 2.0, 0.6, 0.6), ("ground", 0.67, 0.6, 1.0), ("move", 1.5, 0.05), ("hover", 3.0),
           ("ground", 0.25, 0.0, 0.0), ("move", 0.2, -0.05), ("ground", 2.0, 0.0, 0.0)]
    t, z, v, tilt, thrust, contact, _ = flight(cut, seed=6)
    thrust = thrust * (1.0 + np.random.default_rng(8).normal(0.0, 0.002, len(t)))
    mask, found = ground_contact(t, z, v, tilt, thrust, MASS)
    assert len(found) == 2 and found[1].t_start == pytest.approx(7.42, abs=0.1)  # the landing (0.2 s margin), as before
    in_air = (t > 7.2) & (t < 7.35)  # the still 0.25 s at 5 cm after the cut, margins of the landing aside
    assert not mask[in_air].any()


def test_skims_inside_one_interval_read_as_one_sentence():
    """Two skims whose margins merge into one interval beside a rest: the rest's sentence once, and one skim
    sentence with how many, the lowest height and the lowest thrust of them all; skims outside are not told."""
    found = [(1.0, 1.5, "on the landing gear: x"), (1.2, 1.4, "on the landing gear: x")]
    skims = [(2.0, 2.1, 0.025, 0.4), (2.3, 2.4, 0.024, 0.0), (9.0, 9.1, 0.02, 0.0)]
    why = _joined_why(found, skims, 0.8, 2.6, "rotor-plane height", "the landed height 0.024 m", 0.005)
    assert why == ("on the landing gear: x; skimming the floor 2 times: rotor-plane height down to 0.024 m, within "
                   "0.5 cm of the landed height 0.024 m, thrust down to 0 % of the weight: the landing gear may "
                   "touch (a skid or a bounce)")
    one = _joined_why([], skims[:1], 1.9, 2.2, "height", "the landed height 0.024 m", 0.005)
    assert one.startswith("skimming the floor: height down to 0.025 m") and "40 % of the weight" in one


# --- a landed height needs the floor seen carrying the vehicle ------------------------------------------------------

#: m, rotor plane over the body origin in the tests below: resting at Z_LAND the rotor plane is 0.12 m up, d/R 1.2
#: for a 0.1 m rotor (a hexarotor's hover there needs 91 % of the weight in a Cheeseman-Bennett ground effect at mu 2)
PLANE_UP = 0.107
#: share of the weight a still hover needs at the lowest height of the tests below (the ground effect itself)
HOVER_IN_GROUND_EFFECT = 0.91


def _low_hover(phases, seed, low_ratio=HOVER_IN_GROUND_EFFECT, still_below=0.015):
    """A flight from ``phases`` with its rotor-plane heights; still rows within ``still_below`` m of its lowest
    height off the ground read ``low_ratio`` of the weight, every thrust with 0.2 % jitter (not a held stream)."""
    t, z, v, tilt, thrust, contact, _ = flight(phases, seed=seed, z_noise=0.0005)
    d_down = z + PLANE_UP
    low = (d_down < np.min(d_down[~contact]) + still_below) & ~contact
    thrust = np.where(low & (np.abs(v[:, 2]) < 0.02), low_ratio * MASS * GRAVITY, thrust)
    thrust = thrust * (1.0 + np.random.default_rng(seed).normal(0.0, 0.002, len(t)))
    return t, z, v, tilt, thrust, contact, d_down


NEVER_LANDS = [("hover", 4.0), ("move", 2.0, 0.3), ("hover", 2.0), ("move", 2.0, -0.3), ("hover", 6.0)]


def test_a_hover_that_never_lands_is_not_on_the_ground_at_its_lowest_height():
    """A still, level hover at d/R 1.2 reading 91 % of the weight (the ground effect itself) at the lowest height the
    recording reaches, which never lands: the floor is never seen to carry it (the strongest lift allowed there
    could hold a hover at 48 %, so only idling rotors, a thrust under 48 % or one moving while the vehicle does not
    would show it). Its 10 s at the lowest height had been found "on the landing gear": the rows where the ground
    effect is strongest, lost."""
    t, z, v, tilt, thrust, _, d_down = _low_hover(NEVER_LANDS, seed=21)
    lift = _hover_lift_cheeseman_bennett()
    assert 1.0 / lift(0.12) == pytest.approx(0.48, abs=0.01)
    mask, found = ground_contact(t, z, v, tilt, thrust, MASS, d_down=d_down, hover_lift=lift)
    assert found == [] and not mask.any()
    assert landed_height(t, z, v, tilt, thrust, MASS, d_down=d_down, hover_lift=lift) is None
    old, _ = ground_contact(t, z, v, tilt, thrust, MASS, d_down=d_down)  # no lift known: the lowest is a landing
    assert old[(t > 1.0) & (t < 3.5)].all()
    # the rests a point cloud must agree with, found from the body's height with the lift read off the cloud: none;
    # with no surface under the vehicle (lift 1) the same rows would rest (a cloud whose floor is off)
    by_z, _ = ground_contact(t, z, v, tilt, thrust, MASS, lift=lift(d_down))
    assert not by_z.any()
    by_z, _ = ground_contact(t, z, v, tilt, thrust, MASS, lift=np.ones(len(t)))
    assert by_z[(t > 1.0) & (t < 3.5)].all()


def test_the_same_hover_over_a_real_rest_lower_down_rests_only_there():
    """Rotors idling (10 % of the weight) for 3 s at d/R 1.2, then the still hover at 91 % 4 cm higher: the rest is
    left out, the hover kept."""
    phases = [("ground", 3.0, 0.1, 0.1), ("ground", 0.67, 0.1, 1.0), ("move", 1.0, 0.04), ("hover", 4.0)]
    phases += NEVER_LANDS[1:]
    t, z, v, tilt, thrust, contact, d_down = _low_hover(phases, seed=22)
    lift = _hover_lift_cheeseman_bennett()
    mask, found = ground_contact(t, z, v, tilt, thrust, MASS, d_down=d_down, hover_lift=lift)
    assert_matches(found, t, contact)
    assert mask[contact].all() and not mask[t > 5.0].any()
    assert landed_height(t, z, v, tilt, thrust, MASS, d_down=d_down, hover_lift=lift) == pytest.approx(0.12, abs=0.003)


def test_the_vehicles_landed_height_comes_from_the_recordings_that_land():
    """One recording rests (idling) at 0.12 m and hovers 4 cm higher, another only hovers at its lowest, 0.14 m:
    the vehicle's landed height is the first's, seen; with the hover alone, its lowest height, not seen, where
    only a dip moving throughout skims."""
    rest = [("ground", 3.0, 0.1, 0.1), ("ground", 0.67, 0.1, 1.0), ("move", 1.0, 0.04), ("hover", 4.0)]
    lift = _hover_lift_cheeseman_bennett()
    t, z, v, tilt, thrust, _, d_down = _low_hover(rest + NEVER_LANDS[1:], seed=23)
    t2, z2, v2, tilt2, thrust2, _, d_down2 = _low_hover(NEVER_LANDS, seed=24)
    z2, d_down2 = z2 + 0.02, d_down2 + 0.02
    landed = landed_height(t, z, v, tilt, thrust, MASS, d_down=d_down, hover_lift=lift)
    hover = landed_height(t2, z2, v2, tilt2, thrust2, MASS, d_down=d_down2, hover_lift=lift)
    assert hover is None
    assert _vehicle_landed_height([landed, hover], [d_down, d_down2]) == (landed, True)
    low, seen = _vehicle_landed_height([hover], [d_down2])
    assert low == pytest.approx(0.14, abs=0.003) and not seen
    assert _vehicle_landed_height([landed, hover], [d_down, None]) == (None, False)
    mask, _ = ground_contact(t2, z2, v2, tilt2, thrust2, MASS, d_down=d_down2, hover_lift=lift,
                             skim_top=landed + ContactLimits().skim_m)
    assert not mask.any()
    mask, _ = ground_contact(t2, z2, v2, tilt2, thrust2, MASS, d_down=d_down2, hover_lift=lift,
                             skim_top=low + ContactLimits().skim_m, skim_landed=False)
    assert not mask.any()  # its lowest rows are a still hover


def test_a_dip_moving_throughout_skims_where_no_rest_was_seen_but_a_still_hover_there_does_not():
    """A walk that never lands dips 0.3 m to its lowest height and back while moving sideways at 0.2 m/s, the thrust
    down to 88 % of the weight at the bottom: it may touch the floor (real walks' dips to their lowest set point:
    never still, the largest residuals), so it is left out; a still hover at that height is not."""
    phases = [("hover", 3.0), ("move", 1.2, -0.3), ("move", 1.2, 0.3), ("hover", 3.0)]
    t, z, v, tilt, thrust, _, _ = flight(phases, seed=25, z_noise=0.0005, floor=0.3)
    d_down = z - 0.3 + PLANE_UP
    v[(t > 3.0) & (t < 5.4), 0] = 0.2
    bottom = d_down < np.min(d_down) + 0.005
    thrust = np.where(bottom, 0.88 * MASS * GRAVITY, thrust)
    thrust = thrust * (1.0 + np.random.default_rng(25).normal(0.0, 0.002, len(t)))
    lift = _hover_lift_cheeseman_bennett()
    mask, found = ground_contact(t, z, v, tilt, thrust, MASS, d_down=d_down, hover_lift=lift)
    assert mask[bottom].all() and not mask[(t < 3.5) | (t > 5.0)].any()
    assert len(found) == 1 and "(no rest seen there; the vehicle moving)" in found[0].why
    v[(t > 3.0) & (t < 5.4), 0] = 0.0  # the same dip straight down and up: still as it turns, a hover's bottom
    mask, found = ground_contact(t, z, v, tilt, thrust, MASS, d_down=d_down, hover_lift=lift)
    assert found == [] and not mask.any()


def test_rotors_spinning_on_the_gear_deep_in_ground_effect_rest_where_their_thrust_moves_and_the_vehicle_does_not():
    """The simulator's landings: the rotor plane rests at 0.6 rotor radius, where the strongest law allowed has
    its pole (no thrust is too low for a hover there), the rotors at 35-55 % of the weight, never idling. Their
    thrust ramping through 20 % of the weight in a second while the vehicle stays still at one height is what tells
    the floor: a hover's thrust follows its height. Without that reading both ends were missed (a flight of the
    suite's tests, 4-9 N of floor reaction fitted as aerodynamics)."""
    phases = [("ground", 2.0, 0.35, 0.55), ("ground", 0.67, 0.55, 1.0), ("move", 2.0, 0.3), ("hover", 4.0),
              ("move", 2.0, -0.3), ("ground", 0.5, 1.0, 0.55), ("ground", 2.0, 0.55, 0.35)]
    t, z, v, tilt, thrust, contact, _ = flight(phases, seed=26, z_noise=0.0005)
    thrust = thrust * (1.0 + np.random.default_rng(26).normal(0.0, 0.002, len(t)))
    d_down = z + 0.047  # resting at 0.06 m, 0.6 rotor radius
    strongest = _hover_lift_cheeseman_bennett()

    def lift(h):
        x = strongest(h)
        return np.where(x > 0, x, np.inf)  # inside the pole: no bound

    assert np.isinf(lift(0.06))
    mask, found = ground_contact(t, z, v, tilt, thrust, MASS, d_down=d_down, hover_lift=lift)
    assert_matches(found, t, contact)
    assert mask[contact].all()
    no_ramp = ContactLimits(ramp_ratio=np.inf)
    _, missed = ground_contact(t, z, v, tilt, thrust, MASS, d_down=d_down, hover_lift=lift, limits=no_ramp)
    assert missed == []


def test_a_hover_over_a_box_nearer_it_than_the_gear_holds_the_rotors_does_not_hide_the_landings():
    """A blind probe's quadrotor rested on the floor with its rotor plane 0.170 m up and hovered 0.148 m over a 25 cm
    box: the lowest height was that hover, no rest there, and both landings (7.5-7.9 N of floor reaction) had been
    fitted as flight. The still stretches above the lowest are tried: the floor is seen at the rests."""
    phases = TAKEOFF_LANDING[:4] + [("floor", 0.25), ("move", 1.5, -0.073), ("hover", 3.0), ("move", 1.5, 0.073),
                                    ("floor", 0.0)] + TAKEOFF_LANDING[4:]
    t, z, v, tilt, thrust, contact, floor = flight(phases, seed=5, z_noise=0.0005)
    d_down = z - floor + 0.15  # rotor plane 15 cm above the body origin: rests at 0.163 m, hovers at 0.140 m
    over_box = floor > 0
    assert np.min(d_down[over_box]) < np.min(d_down[contact]) - 0.015
    lift = _hover_lift_cheeseman_bennett(mu=2.0)
    low = landed_height(t, z, v, tilt, thrust, MASS, d_down=d_down, calibrate=False, hover_lift=lift)
    assert low == pytest.approx(Z_LAND + 0.15, abs=0.002)
    mask, found = ground_contact(t, z, v, tilt, thrust, MASS, d_down=d_down, calibrate=False, hover_lift=lift)
    assert_matches(found, t, contact)
    assert not mask[over_box].any()
    said = "the lowest still height where the floor is seen to carry the vehicle; it came down to 0.139 m"
    assert said in found[0].why
