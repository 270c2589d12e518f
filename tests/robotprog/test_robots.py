"""Robot models from example-robot-data by name or URDF path."""

from __future__ import annotations

import numpy as np
import pytest

from factory.core.errors import CellError
from robotprog.robots import KNOWN_ROBOTS, example_robot_data_dir, load_robot, robot_urdf


@pytest.mark.parametrize("name, dof", [("ur5", 6), ("ur10", 6), ("panda", 7)])
def test_known_robots_load_with_limits(name: str, dof: int) -> None:
    r = load_robot(name)
    assert r.dof == dof == len(r.joint_names)
    assert r.q_lower.shape == r.q_upper.shape == r.v_max.shape == (dof,)
    assert (r.q_lower < r.q_upper).all() and (r.v_max > 0).all()
    # The flange is somewhere sensible: within 1.5 m of the base at the neutral pose.
    assert 0.05 < np.linalg.norm(r.fk(np.zeros(dof))[:3, 3]) < 1.5


def test_panda_fingers_are_locked() -> None:
    r = load_robot("panda")
    assert not any("finger" in j for j in r.joint_names)


def test_collision_geometry_resolves_package_meshes() -> None:
    r = load_robot("ur5", collision=True)
    assert r.collision is not None and r.collision.ngeoms >= 6
    # package://example-robot-data/... resolved to real files under the share folder.
    share = str(example_robot_data_dir())
    files = [g.meshPath for g in r.collision.geometryObjects if g.meshPath.endswith((".stl", ".dae", ".obj"))]
    assert len(files) >= 6 and all(f.startswith(share) for f in files)


def test_every_known_robot_urdf_exists() -> None:
    for name in KNOWN_ROBOTS:
        assert robot_urdf(name).is_file(), name


def test_urdf_path_loads_like_the_name() -> None:
    by_path = load_robot(robot_urdf("ur5"), base_frame="base_link", flange_frame="tool0")
    by_name = load_robot("ur5")
    q = np.array([0.3, -1.2, 1.1, -0.4, 0.7, 0.2])
    np.testing.assert_allclose(by_path.fk(q), by_name.fk(q), atol=1e-12)


def test_unknown_name_lists_known_robots() -> None:
    with pytest.raises(CellError, match="unknown robot 'ur7'.*panda.*ur5"):
        load_robot("ur7")


def test_missing_urdf_file(tmp_path) -> None:
    with pytest.raises(CellError, match="not found"):
        load_robot(tmp_path / "nope.urdf")


def test_bad_frame_name() -> None:
    with pytest.raises(CellError, match="flange_frame 'gripper_tip'"):
        load_robot("ur5", flange_frame="gripper_tip")


def test_maker_from_the_model_name() -> None:
    from factory.core.resources import FIXTURES
    from robotprog.robots import maker_of

    assert load_robot("ur5").maker == "Universal Robots" and load_robot("panda").maker is None
    arm = load_robot(FIXTURES / "robots/kuka_kr6_r900_sixx/kuka_kr6_r900_sixx.urdf", flange_frame="tool0")
    assert arm.maker == "KUKA"
    assert maker_of("abb_irb120") == "ABB" and maker_of("ur10e") == "Universal Robots"
    assert maker_of("urdf_arm") is None and maker_of("kr6") is None
    # the datasheet's axis speeds [deg/s] and ranges are the URDF's limits
    np.testing.assert_allclose(np.degrees(arm.v_max), [360, 300, 360, 381, 388, 615], atol=1e-4)
    np.testing.assert_allclose(np.degrees(arm.q_lower), [-170, -190, -120, -185, -120, -350], atol=1e-4)
    np.testing.assert_allclose(np.degrees(arm.q_upper), [170, 45, 156, 185, 120, 350], atol=1e-4)
