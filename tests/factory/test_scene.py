"""Foxglove scene messages with embedded glTF meshes: the mesh survives the trip Z-up -> GLB ->
Foxglove's Y-up-to-Z-up turn, and the message serialises with the foxglove_msgs definitions."""

from __future__ import annotations

import io
import json
import struct

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from factory.core.errors import McapError
from factory.rosmsgs import TYPESTORE
from factory.scene import GLB_MEDIA_TYPE, glb_bytes, model_entity, scene_update

# What Foxglove's ModelCache does to every glTF model it loads: rotateX(+pi/2) (Y-up -> Z-up).
FOXGLOVE_LOAD_TURN = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def glb_positions(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of a one-mesh GLB, read with trimesh."""
    mesh = trimesh.load(io.BytesIO(data), file_type="glb", force="mesh", process=False)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def test_glb_is_a_gltf_2_binary_with_positions_and_indices():
    box = trimesh.creation.box(extents=(0.1, 0.2, 0.3))
    data = glb_bytes(box.vertices, box.faces)
    magic, version, length = struct.unpack("<4sII", data[:12])
    assert (magic, version, length) == (b"glTF", 2, len(data))
    size, kind = struct.unpack("<I4s", data[12:20])
    doc = json.loads(data[20:20 + size])
    assert kind == b"JSON" and doc["asset"]["version"] == "2.0"
    (prim,) = doc["meshes"][0]["primitives"]
    assert prim["mode"] == 4 and "POSITION" in prim["attributes"] and "indices" in prim


@settings(max_examples=40, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(3, 30), st.just(3)), elements=st.floats(-2, 2)), st.data())
def test_foxglove_shows_the_mesh_in_its_ros_frame(vertices, data):
    n = len(vertices)
    faces = np.array(data.draw(st.lists(st.tuples(*[st.integers(0, n - 1)] * 3), min_size=1, max_size=20)))
    back, back_faces = glb_positions(glb_bytes(vertices, faces))
    np.testing.assert_array_equal(back_faces, faces)
    # float32 in the file; Foxglove's load turn brings the glTF Y-up mesh back Z-up
    np.testing.assert_allclose(back @ FOXGLOVE_LOAD_TURN.T, vertices, atol=1e-6)


@pytest.mark.parametrize("vertices, faces, message", [
    (np.zeros((3, 2)), [[0, 1, 2]], "vertices"),
    (np.array([[0, 0, np.nan]] * 3), [[0, 1, 2]], "finite"),
    (np.zeros((3, 3)), np.zeros((0, 3), int), "m >= 1"),
    (np.zeros((3, 3)), [[0, 1, 3]], "out of range"),
    (np.zeros((3, 3)), [[0.0, 1.0, 2.0]], "integers"),
])
def test_bad_meshes_are_refused(vertices, faces, message):
    with pytest.raises(McapError, match=message):
        glb_bytes(vertices, np.asarray(faces))


def test_entity_serialises_and_keeps_its_placement():
    box = trimesh.creation.box(extents=(0.1, 0.2, 0.3))
    pose = np.eye(4)
    pose[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    pose[:3, 3] = [0.1, 0.2, 0.3]
    msg = scene_update([model_entity("link_0", "link", pose, box.vertices, box.faces, (0.9, 0.9, 0.9, 1.0),
                                     1_500_000_000)])
    raw = TYPESTORE.serialize_cdr(msg, "foxglove_msgs/msg/SceneUpdate")
    back = TYPESTORE.deserialize_cdr(raw, "foxglove_msgs/msg/SceneUpdate")
    (entity,) = back.entities
    assert (entity.id, entity.frame_id, entity.frame_locked) == ("link_0", "link", True)
    assert (entity.timestamp.sec, entity.timestamp.nanosec) == (1, 500_000_000)
    (model,) = entity.models
    assert model.media_type == GLB_MEDIA_TYPE and model.url == "" and model.override_color
    p, q = model.pose.position, model.pose.orientation
    assert (p.x, p.y, p.z) == (0.1, 0.2, 0.3)
    np.testing.assert_allclose([q.x, q.y, q.z, q.w], [0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-12)
    vertices, _ = glb_positions(bytes(model.data))
    np.testing.assert_allclose(vertices @ FOXGLOVE_LOAD_TURN.T, box.vertices, atol=1e-7)
    with pytest.raises(McapError, match="colour"):
        model_entity("x", "link", pose, box.vertices, box.faces, (255, 0, 0, 1), 0)
