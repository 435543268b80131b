"""One vehicle lands at one height: recordings landing apart are moved to one (``gap/landed_heights.py``)."""

from __future__ import annotations

import numpy as np

import pytest

from uavturb.gap.finder import analyse
from uavturb.gap.landed_heights import LANDED_ALIGN_MAX_M, LandedHeights, landed_alignment, moved_heights
from uavturb.gap.report import write_markdown
from uavturb.io.ply import read_ply, write_ply
from uavturb.io.reader import load_recordings
from uavturb.sim.flights.condition_schema import Conditions
from uavturb.sim.flights.conditions import generate_conditioned_flight
from uavturb.sysid.flight_data import FlightData


def test_three_airframes_landing_six_millimetres_apart_are_moved_to_their_median():
    # Neural-Swarm's June Crazyflies cf50, cf51, cf52 land at these rotor-plane heights
    landed = landed_alignment([0.024, 0.027, 0.030])
    assert landed.applied and landed.common_m == pytest.approx(0.027)
    assert np.allclose(landed.shifts, [0.003, 0.0, -0.003])
    assert landed.spread_m == pytest.approx(0.006) and landed.uncertainty_m == 0.0  # every recording moved
    said = landed.sentence(["cf50", "cf51", "cf52"])
    assert "6.0 mm apart" in said and "+3.0 mm (cf50)" in said and "-3.0 mm (cf52)" in said
    back = LandedHeights.from_report(landed.as_report(["a", "b", "c"]))
    assert back == landed


def test_a_recording_that_never_lands_is_not_moved_and_the_errors_cover_half_the_spread():
    landed = landed_alignment([0.024, None, 0.030])
    assert landed.applied and landed.shifts == pytest.approx((0.003, 0.0, -0.003))
    assert landed.uncertainty_m == pytest.approx(0.003)
    assert "walk never lands" in landed.sentence(["takeoff", "walk", "landing"])


def test_landings_alike_or_too_far_apart_move_nothing():
    alike = landed_alignment([0.024, 0.0265])  # within a gear's give and the motion capture's noise
    assert not alike.applied and alike.shifts == (0.0, 0.0) and alike.uncertainty_m == 0.0
    assert "one height" in alike.sentence(["a", "b"])
    apart = landed_alignment([0.024, 0.024 + LANDED_ALIGN_MAX_M + 0.005])  # no one gear: not moved, covered
    assert not apart.applied and apart.uncertainty_m == pytest.approx((LANDED_ALIGN_MAX_M + 0.005) / 2)
    assert "25.0 mm apart, more than the 20 mm by which one vehicle on one landing gear can differ" in apart.sentence(
        ["a", "b"]) and "taken as recorded" in apart.sentence(["a", "b"])
    for one in ([0.024], [0.024, None], [None, None], []):
        landed = landed_alignment(one)
        assert not landed.applied and landed.as_report(["x"] * len(one)) is None and landed.uncertainty_m == 0.0


def test_moving_a_reference_moves_both_heights_the_other_way():
    n = 4
    fd = FlightData(name="f", t_ns=np.arange(n), t=np.arange(n) * 0.01, p=np.zeros((n, 3)), q=np.tile([1.0, 0, 0, 0],
                    (n, 1)), v=np.zeros((n, 3)), w=np.zeros((n, 3)), acc=None, rotor_speeds=np.ones((n, 4)),
                    dv=np.zeros((n, 3)), dw=np.zeros((n, 3)), d_down=np.array([0.03, 0.05, np.inf, 0.1]),
                    d_up=np.array([2.0, np.inf, 1.0, 1.9]), window=5)
    moved = moved_heights(fd, -0.003)
    assert np.allclose(moved.d_down, [0.027, 0.047, np.inf, 0.097])
    assert np.allclose(moved.d_up, [2.003, np.inf, 1.003, 1.903])
    assert moved_heights(fd, 0.0) is fd
    assert np.array_equal(fd.d_down, [0.03, 0.05, np.inf, 0.1])  # the flight given is left as it was


def test_two_flights_whose_heights_count_from_references_8_mm_apart_land_at_one_height(tmp_path):
    """Two hexarotor flights under a ground effect (mu = 2) that land at both ends; the second one's point cloud
    lies 8 mm low (its heights all read 8 mm high, as a motion capture origin set anew would make them): the finder
    reads the landings 8 mm apart, moves each 4 mm towards the other, says so, and names mu within its error."""
    paths = []
    for seed in (1700, 1701):
        path = tmp_path / f"contact-{seed}"
        generate_conditioned_flight("hex", {"ground_effect": {"mu": 2.0}}, duration=60.0, kind="low_passes",
                                    seed=seed, conditions=Conditions(ground_contact_s=3.0), out=path)
        paths.append(path)
    cloud = paths[1] / "mav0" / "pointcloud0" / "data.ply"
    points = read_ply(cloud)
    points[:, 2] -= 0.008
    write_ply(cloud, points)
    report, _ = analyse(load_recordings(paths), {})
    landed = report["height_reference"]["landed_heights"]
    assert landed["applied"] and landed["spread_m"] == pytest.approx(0.008, abs=0.001)
    low, high = landed["recordings"]
    assert low["recording"] == str(paths[0]) and low["shift_m"] == pytest.approx(0.004, abs=0.001)
    assert high["shift_m"] == pytest.approx(-0.004, abs=0.001)
    assert report["height_uncertainty_m"] == pytest.approx(0.01)  # both moved: the stated reference's +-1 cm
    (ground,) = [e for e in report["effects"] if e["name"] == "ground_effect"]
    assert abs(ground["params"]["mu"] - 2.0) < 2 * ground["stderr"]["mu"]
    write_markdown(tmp_path, report, [])
    md = (tmp_path / "report.md").read_text()
    assert "**Landed heights**" in md and f"{paths[0].name})" in md
