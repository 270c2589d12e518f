"""Robot visual meshes: placed where Pinocchio's own geometry placement puts them."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from robotprog.robots import example_robot_data_dir, load_robot
from robotprog.visuals import robot_visuals


@pytest.mark.parametrize("name", ["ur5", "panda"])
def test_visuals_in_link_frames_land_where_pinocchio_places_them(name):
    """Link pose (forward kinematics of the link frame) times the visual's pose in the link must
    equal Pinocchio's world placement of the same geometry, at a random configuration."""
    robot = load_robot(name)
    visuals = robot_visuals(robot)
    model = robot.model
    geom = pin.buildGeomFromUrdf(model, str(robot.urdf), pin.GeometryType.VISUAL,
                                 package_dirs=[str(example_robot_data_dir())])
    q = pin.randomConfiguration(model, model.lowerPositionLimit, model.upperPositionLimit)
    data, gdata = model.createData(), geom.createData()
    pin.forwardKinematics(model, data, q)
    pin.updateFramePlacements(model, data)
    pin.updateGeometryPlacements(model, data, geom, gdata)
    assert [v.name for v in visuals] == [g.name for g in geom.geometryObjects]
    for v, placed in zip(visuals, gdata.oMg):
        link = data.oMf[model.getFrameId(v.link)].homogeneous
        np.testing.assert_allclose(link @ v.pose, placed.homogeneous, atol=1e-9)


def test_ur5_meshes_are_the_arm_in_metres():
    visuals = robot_visuals(load_robot("ur5"))
    assert [v.link for v in visuals] == ["base_link", "shoulder_link", "upper_arm_link", "forearm_link",
                                         "wrist_1_link", "wrist_2_link", "wrist_3_link"]
    for v in visuals:
        assert len(v.faces) > 100 and v.faces.max() < len(v.vertices) and not v.vertices.flags.writeable
        size = np.ptp(v.vertices, axis=0)
        assert 0.03 < size.max() < 0.6, (v.name, size)  # UR5 links are 0.1-0.5 m long, not mm
    assert sum(len(v.faces) for v in visuals) > 50_000
    assert robot_visuals(load_robot("ur5")) is visuals  # read once
