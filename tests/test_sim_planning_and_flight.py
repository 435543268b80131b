"""Reference trajectories through procedural scenes, and closed-loop flights along them."""

from __future__ import annotations

import numpy as np
import pytest

from uavturb.errors import InputError
from uavturb.physics.vehicle import QUADROTOR
from uavturb.scene import procedural, queries
from uavturb.sim.dataset import flying, navigation, plan_plot, planning

RADIUS = QUADROTOR.arm_length + QUADROTOR.rotor_radius


@pytest.fixture(scope="module")
def plans():
    out = []
    for seed in (0, 1, 2, 3):
        sc = procedural.generate_scene(seed)
        out.append((sc, planning.plan_trajectory(sc, seed, rotor_radius=QUADROTOR.rotor_radius)))
    return out


def _samples(plan, step=0.02):
    t = np.arange(0.0, plan.reference.duration + 1e-9, step)
    return t, plan.reference(t)


def test_christofides_order_is_a_tour_of_every_point():
    rng = np.random.default_rng(0)
    ang = rng.permutation(np.linspace(0, 2 * np.pi, 9, endpoint=False))
    pts = np.c_[np.cos(ang), np.sin(ang)]
    L = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    order = navigation.christofides_order(L, start=3)
    assert order[0] == 3 and sorted(order) == list(range(9))
    closed = order + [order[0]]
    tour = sum(L[a, b] for a, b in zip(closed[:-1], closed[1:]))
    optimum = 9 * 2 * np.sin(np.pi / 9)  # the regular polygon
    assert optimum - 1e-9 <= tour <= 1.5 * optimum


def test_astar_shortest_free_path_matches_dijkstra():
    occ = np.zeros((30, 20), bool)
    occ[15, :17] = True  # a wall with a gap at the top
    grid = navigation.NavGrid(occ, np.zeros(2), 0.1, 1.0, np.zeros_like(occ, float), ~occ)
    path = navigation.astar(occ, (2, 2), (28, 2))
    assert path[0] == (2, 2) and path[-1] == (28, 2)
    steps = np.diff(np.asarray(path), axis=0)
    assert np.abs(steps).max() == 1 and not any(occ[c] for c in path)
    for (i, j), (di, dj) in zip(path[:-1], steps):  # no corner cutting
        if di and dj:
            assert not occ[i + di, j] and not occ[i, j + dj]
    length = 0.1 * sum(np.hypot(*s) for s in steps)
    from scipy.sparse.csgraph import dijkstra

    g, node = grid.graph()
    ref = dijkstra(g, indices=node[2, 2])[node[28, 2]]
    assert length == pytest.approx(ref, abs=1e-9)
    occ2 = occ.copy()
    occ2[15, :] = True
    assert navigation.astar(occ2, (2, 2), (28, 2)) == []
    corners = navigation.simplify_path(grid, grid.to_world(np.asarray(path)))
    assert 3 <= len(corners) < len(path)
    assert all(grid.segment_free(a, b) for a, b in zip(corners[:-1], corners[1:]))


def test_plan_segments_free_and_collision_free(plans):
    for sc, plan in plans:
        assert sorted(plan.order) == list(range(len(plan.points)))
        assert plan.order[0] == 0 and plan.kinds[0] == "floor"
        t, sp = _samples(plan)
        cruise = np.abs(sp.p[:, 2] - plan.grid.z) < 1e-6
        assert cruise.any()
        assert plan.grid.free_at(sp.p[cruise, :2]).all(), sc.seed  # legs stay in the free map
        # every reference point clears the scene by the vehicle's radius
        assert not queries.collides(sc, sp.p, RADIUS, 0.005).any(), sc.seed


def test_yaw_faces_the_direction_of_travel(plans):
    for _, plan in plans:
        _, sp = _samples(plan)
        vh = np.linalg.norm(sp.v[:, :2], axis=1)
        moving = vh > 0.05
        assert moving.sum() > 100
        heading = np.c_[np.cos(sp.yaw), np.sin(sp.yaw)][moving]
        cosang = np.sum(heading * sp.v[moving, :2], axis=1) / vh[moving]
        assert cosang.min() > 1 - 1e-9
        # and the yaw does not turn while moving horizontally
        assert np.abs(sp.yaw_rate[moving]).max() < 1e-9


def test_altitude_profile_takeoffs_landings_low_hovers_edges(plans):
    top_landings = edges = 0
    for sc, plan in plans:
        ref = plan.reference
        phases = ref.notes
        assert {"takeoff", "landing", "hover_low", "cruise", "rest"} <= set(phases)
        ends = ref(np.array([0.0, ref.duration]))
        d_end = queries.height_below(sc, ends.p)
        assert np.all(d_end < 0.05)  # starts and ends landed (0.02 m for the quadrotor)
        for t0, t1 in phases["landing"]:
            sp = ref(np.array([t1]))
            surf = sp.p[0, 2] - queries.height_below(sc, sp.p)[0]
            top_landings += surf > 0.1
        for t0, t1 in phases.get("edge_pass", []):
            sp = ref(np.linspace(t0, t1, 50))
            surf = sp.p[:, 2] - queries.height_below(sc, sp.p)
            assert surf.max() - surf.min() > 0.1  # the surface below changes
            assert np.ptp(sp.p[:, 2]) < 1e-9  # at one height
            edges += 1
        t, sp = _samples(plan)
        d = queries.height_below(sc, sp.p)
        assert (d < 0.5).mean() > 0.1
    assert top_landings >= 1 and edges >= 2


def test_plan_is_deterministic():
    sc = procedural.generate_scene(5)
    a, b = planning.plan_trajectory(sc, 11), planning.plan_trajectory(sc, 11)
    c = planning.plan_trajectory(sc, 12)
    t = np.linspace(0, 30, 301)
    assert a.reference.duration == b.reference.duration
    assert np.array_equal(a.reference(t).p, b.reference(t).p)
    assert not np.array_equal(a.reference(t).p, c.reference(t).p)


def test_collides_known_answers():
    sc = procedural.generate_scene(0)
    wall = sc.boxes[list(sc.box_kinds).index("wall")]
    inside_wall = (wall[0] + wall[1]) / 2
    grid = planning.build_grid(sc, 1.0)
    xy = grid.to_world(np.argwhere(grid.flat & (grid.surface < 0.01))[0])[0]  # clear floor below 1 m
    near_wall = np.r_[wall[0, 0] - RADIUS + 0.01, (wall[0, 1] + wall[1, 1]) / 2, 1.0]
    p = np.array([inside_wall, [*xy, 1.0], [*xy, 0.02], [*xy, 0.001], near_wall, [*xy, 50.0]])
    assert queries.collides(sc, p, RADIUS, 0.01).tolist() == [True, False, False, True, True, True]
    assert queries.collides(sc, p, 0.0, 0.0).tolist()[:4] == [True, False, False, False]


def test_fly_trajectory_short_flight_both_controllers():
    sc = procedural.generate_scene(3)
    plan = planning.plan_trajectory(sc, 3, rotor_radius=QUADROTOR.rotor_radius)
    for ctrl in ("geometric", "mpc"):
        X, W, t, info = flying.fly_trajectory(sc, QUADROTOR, 3, ctrl, plan=plan, duration=5.0)
        assert X.shape == (101, 13) and W.shape == (101, 4) and t.shape == (101,)
        assert np.allclose(np.diff(t), 0.05)
        assert not info["collided"] and info["collisions"] == 0
        assert np.allclose(np.linalg.norm(X[:, 3:7], axis=1), 1.0)
        assert info["tracking_error"].max() < 0.02, ctrl
        assert np.all((W >= 0) & (W <= QUADROTOR.max_rotor_speed))
        # take-off from the floor: low, in ground effect, with its force up
        assert info["d_down"][0] < 0.05 and info["effect_force"][0, 2] > 0
    X2, W2, _, _ = flying.fly_trajectory(sc, QUADROTOR, 3, "mpc", plan=plan, duration=5.0)
    assert np.array_equal(X, X2) and np.array_equal(W, W2)  # deterministic


def test_fly_trajectory_truncates_at_collision():
    sc = procedural.generate_scene(3)
    plan = planning.plan_trajectory(sc, 3)
    # a vehicle much wider than the planner's clearance hits something on the way
    wide = QUADROTOR.with_params(arm_length=0.6)
    X, _, t, info = flying.fly_trajectory(sc, wide, 3, "geometric", plan=plan)
    assert info["collided"] and info["collisions"] == 1
    assert len(X) < int(plan.reference.duration * 20)
    assert t[-1] < info["collision_time"]
    assert not queries.collides(sc, X[:, 0:3], 0.6 + QUADROTOR.rotor_radius, 0.01).any()


def test_bad_inputs():
    sc = procedural.generate_scene(0)
    with pytest.raises(InputError, match="controller"):
        flying.fly_trajectory(sc, "quad", 0, controller="pid")
    with pytest.raises(InputError, match="n_points"):
        planning.plan_trajectory(sc, 0, planning.PlanConfig(n_points=0))
    with pytest.raises(InputError, match="camera_rate"):
        flying.fly_trajectory(sc, "quad", 0, camera_rate=30.0, duration=1.0)


@pytest.mark.slow
def test_full_mpc_flights_track_and_stay_clear():
    for seed in (1, 4):
        sc = procedural.generate_scene(seed)
        X, W, t, info = flying.fly_trajectory(sc, "quad", seed, "mpc")
        assert not info["collided"]
        assert info["tracking_error"].max() < 0.03
        assert (info["d_down"] < 0.5).mean() > 0.1
        assert np.all(W <= QUADROTOR.max_rotor_speed)


def test_plot_flight_writes_png(tmp_path):
    sc = procedural.generate_scene(2)
    plan = planning.plan_trajectory(sc, 2)
    out = plan_plot.plot_flight(sc, plan, str(tmp_path / "flight.png"))
    data = (tmp_path / "flight.png").read_bytes()
    assert out.endswith("flight.png") and data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flight.png"]  # no temporary left
