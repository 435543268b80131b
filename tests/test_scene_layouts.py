"""Single-room layouts of the one scene model (uavturb.scene.layouts) and the one surface query over
boxes (uavturb.scene.boxes.surface_heights) behind every height: known answers, agreement of the
query's users bit for bit, bad inputs."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from uavturb.errors import InputError
from uavturb.scene.boxes import BoxHeights, box_heights, surface_heights
from uavturb.scene.indoor import load_scene_mesh
from uavturb.scene.layouts import box_room, euroc_vicon_room, floor_boxes, room_size, table_room
from uavturb.scene.queries import collides, height_above, height_below, surface_below


@pytest.fixture(scope="module")
def room():
    """6 x 4 m, 2.5 m high; a 1 x 1 m table (top 0.75) at the origin, a crate (top 0.4) at x 2-2.5."""
    return box_room((6.0, 4.0), 2.5, [(-0.5, 0.5, -0.5, 0.5, 0.75), (2.0, 2.5, -1.0, 1.0, 0.4)], ["table", "crate"])


def test_a_layout_is_a_scene_of_one_room(room):
    assert room.kind == "room" and room.has_boxes and room.ceiling_height == 2.5
    assert [f.kind for f in room.furniture] == ["table", "crate"] and room_size(room) == (6.0, 4.0)
    assert floor_boxes(room) == [(-0.5, 0.5, -0.5, 0.5, 0.75), (2.0, 2.5, -1.0, 1.0, 0.4)]
    assert list(room.box_kinds) == ["floor", "ceiling", "wall", "wall", "wall", "wall", "table", "crate"]
    assert list(room.box_owner) == [-1] * 6 + [0, 1]
    assert len(room.mesh.faces) == 12 * 3  # the inner shell, then one box per piece of furniture
    assert np.allclose(room.mesh.bounds, [[-3.0, -2.0, 0.0], [3.0, 2.0, 2.5]])
    # outside the room's walls a vehicle collides; inside, clear of the furniture, it does not
    hit = collides(room, np.array([[3.2, 0.0, 1.0], [-1.5, 1.0, 1.0], [0.0, 0.0, 0.7]]), radius=0.1)
    assert hit.tolist() == [True, False, True]


def test_the_surface_below_and_the_heights_agree(room):
    xy = np.array([[0.0, 0.0], [2.2, 0.5], [-2.0, 1.5], [0.55, 0.0]])
    assert surface_below(room, xy).tolist() == [0.75, 0.4, 0.0, 0.0]
    assert surface_below(room, xy, margin=0.1).tolist() == [0.75, 0.4, 0.0, 0.75]  # the table grown by 10 cm
    p = np.c_[xy, np.full(4, 1.2)]
    assert np.array_equal(height_below(room, p), 1.2 - surface_below(room, xy))
    assert np.array_equal(height_above(room, p), np.full(4, 2.5 - 1.2))
    below, above = surface_heights(room.boxes, np.array([[0.0, 0.0, 1.0], [9.0, 9.0, 1.0]]))
    assert below.tolist() == [0.75, -np.inf] and above.tolist() == [2.5, np.inf]  # off the floor: nothing


def test_one_position_at_a_time_answers_bit_for_bit(room):
    """The closed loop's per-position query (BoxHeights) and the vectorised one are the same query."""
    rng = np.random.default_rng(0)
    p = np.c_[rng.uniform(-3, 3, 300), rng.uniform(-2, 2, 300), rng.uniform(0.0, 2.5, 300)]
    query = BoxHeights(room.boxes)
    one = np.array([[query.d_down(q[None])[0], query.d_up(q[None])[0]] for q in p])
    assert np.array_equal(one[:, 0], box_heights(room.boxes, p, -1.0))
    assert np.array_equal(one[:, 1], box_heights(room.boxes, p, 1.0))


def test_table_room_and_the_euroc_stand_in():
    r = table_room()
    assert floor_boxes(r) == [pytest.approx((1.2, 2.4, 0.5, 1.3, 0.75))] and r.furniture[0].kind == "table"
    eu = euroc_vicon_room()
    assert room_size(eu) == (8.0, 7.0) and eu.ceiling_height == 3.2
    assert [b[4] for b in floor_boxes(eu)] == [0.75, 0.45, 0.2, 0.6]
    assert surface_below(eu, np.array([[1.5, 1.0], [1.3, -2.0]])).tolist() == [0.75, 0.6]


@pytest.mark.parametrize("args, match", [
    (((0.0, 4.0), 2.5, []), "size and ceiling must be positive"),
    (((6.0, 4.0), 2.5, [(0.0, 1.0, 0.0, 1.0, 2.5)]), "0 < top < ceiling"),
    (((6.0, 4.0), 2.5, [(1.0, 0.0, 0.0, 1.0, 0.5)]), "x_min < x_max"),
])
def test_bad_rooms_are_refused(args, match):
    with pytest.raises(InputError, match=match):
        box_room(*args)
    with pytest.raises(InputError, match="1 boxes but 2 kinds"):
        box_room((6.0, 4.0), 2.5, [(0.0, 1.0, 0.0, 1.0, 0.5)], ["table", "crate"])


def test_the_surface_below_needs_boxes(tmp_path):
    path = tmp_path / "floor.ply"
    trimesh.creation.box(extents=(2.0, 2.0, 0.1)).export(path)
    with pytest.raises(InputError, match="needs a scene made of boxes"):
        surface_below(load_scene_mesh(path), np.zeros((1, 2)))
