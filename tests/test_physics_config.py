from pathlib import Path

import pytest
import yaml

from uavturb.errors import InputError
from uavturb.io.physics_config import load_physics_config, write_physics_config
from uavturb.physics.effects import DEFAULT_EFFECTS

CONF = Path(__file__).resolve().parents[1] / "uavturb" / "conf" / "physics" / "default.yaml"


def test_default_config_file_matches_code():
    assert load_physics_config(CONF)["effects"] == DEFAULT_EFFECTS


def test_round_trip_and_bad_keys(tmp_path):
    p = write_physics_config(tmp_path / "c.yaml", {"rotor_drag": {"k_d": 8e-5}, "wind": {"f_x": 0.1, "f_y": 0.2}})
    assert load_physics_config(p)["effects"] == {"rotor_drag": {"k_d": 8e-5}, "wind": {"f_x": 0.1, "f_y": 0.2}}
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"effects": {"rotor_drag": {"kd": 1.0}}}))
    with pytest.raises(InputError, match="bad.yaml.*unknown parameter"):
        load_physics_config(bad)
    bad.write_text(yaml.safe_dump({"efects": {}}))
    with pytest.raises(InputError, match="unknown key"):
        load_physics_config(bad)
