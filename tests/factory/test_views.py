"""CAM views: markers carry the job's cutter locations in metres, kinds of motion apart."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from cadcam.model import CuttingData, Job, Motion, Operation, Setup, Tool
from factory.core.units import MM_PER_M
from factory.views import heightfield_mesh, job_messages, toolpath_markers
from factory.core.errors import McapError
from factory.mcaplog import McapLog

R, C, P = Motion.RAPID, Motion.CUT, Motion.PLUNGE
TOOL = Tool(1, "6 mm flat", "flat", 6.0, 0.0, 20.0, 3, 30.0)
CUT = CuttingData(10000, 800, 300)


def make_op(name: str, kind: str, points: np.ndarray, motion: list[Motion]) -> Operation:
    return Operation(name, kind, TOOL, CUT, points, np.array(motion, dtype=np.int8))


def sample_job() -> Job:
    rng = np.random.default_rng(7)
    # Two feed runs separated by a retract/rapid/plunge, as a roughing pass between regions.
    motion = [R, P, C, C, C, R, R, R, P, C, C]
    rough = make_op("rough z-level", "roughing", rng.uniform([0, 0, -20], [80, 60, 5], (len(motion), 3)), motion)
    finish = make_op("finish raster", "raster", rng.uniform([0, 0, -20], [80, 60, 5], (6, 3)), [R, C, C, C, C, C])
    setup = Setup(stock_min=[0, 0, -25], stock_max=[80, 60, 0], transform_mesh_to_work=np.eye(4))
    return Job("bracket", setup, (rough, finish))


def pts(marker: object) -> np.ndarray:
    return np.array([[p.x, p.y, p.z] for p in marker.points]).reshape(-1, 3)


def segments_of(op: Operation, kind: Motion) -> np.ndarray:
    k = np.nonzero(op.motion[1:] == kind)[0]
    return np.stack([op.points[k], op.points[k + 1]], axis=1).reshape(-1, 3)


def test_toolpath_markers_are_op_points_in_metres_with_kinds_apart() -> None:
    job = sample_job()
    markers = toolpath_markers(job)
    by_key = {(m.ns, m.id): m for m in markers}
    assert all(m.type == m.LINE_LIST and m.header.frame_id == "work" for m in markers)
    for i, op in enumerate(job.operations):
        ns = f"{i + 1:02d} {op.name}"
        total = 0
        for mid, kind in ((0, C), (1, P), (2, R)):
            expected = segments_of(op, kind) / 1000.0
            if len(expected) == 0:
                assert (ns, mid) not in by_key
                continue
            np.testing.assert_array_equal(pts(by_key[(ns, mid)]), expected)
            total += len(expected) // 2
        assert total == len(op.points) - 1  # every move drawn exactly once
    rough = job.operations[0]
    # No segment of the feed markers bridges the rapids between the two runs.
    feed = np.concatenate([pts(by_key[("01 rough z-level", 0)]), pts(by_key[("01 rough z-level", 1)])])
    rapid_ends = rough.points[[5, 6, 7]] / 1000.0
    assert not any((feed == e).all(axis=1).any() for e in rapid_ends[:2])
    assert by_key[("01 rough z-level", 2)].color.r > by_key[("01 rough z-level", 2)].color.b
    # Roughing and finishing differ in colour.
    rc, fc = by_key[("01 rough z-level", 0)].color, by_key[("02 finish raster", 0)].color
    assert (rc.r, rc.g, rc.b) != (fc.r, fc.g, fc.b)


def test_job_messages_topics_frames_part_and_stock() -> None:
    job = sample_job()
    v = np.array([[10, 10, -25], [70, 10, -25], [40, 50, -25], [40, 30, -5]], dtype=float)
    f = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    msgs = job_messages(job, v, f, stamp_ns=42)
    topics = {t: (m, latched) for t, m, latched in msgs}
    assert set(topics) == {"/tf_static", "/cam/toolpath", "/cam/part", "/cam/stock"}
    assert all(latched for _, latched in topics.values())
    (tf,) = topics["/tf_static"][0].transforms
    assert (tf.header.frame_id, tf.child_frame_id) == ("world", "work")
    assert tf.transform.rotation.w == 1.0 and tf.transform.translation.z == 0.0
    (part,) = topics["/cam/part"][0].markers
    assert part.type == part.TRIANGLE_LIST and part.header.stamp.nanosec == 42
    np.testing.assert_array_equal(pts(part), v[f.reshape(-1)] / 1000.0)
    (stock,) = topics["/cam/stock"][0].markers
    assert stock.type == stock.CUBE and stock.color.a < 1
    p, s = stock.pose.position, stock.scale
    np.testing.assert_allclose([p.x, p.y, p.z, s.x, s.y, s.z], [0.04, 0.03, -0.0125, 0.08, 0.06, 0.025])


def test_job_messages_survive_the_log(tmp_path: Path) -> None:
    job = sample_job()
    path = tmp_path / "job.mcap"
    with McapLog(path, stage="toolpath") as log:
        for topic, msg, latched in job_messages(job, np.zeros((3, 3)), np.array([[0, 1, 2]])):
            log.write(topic, msg, 0, latched=latched)
    with open(path, "rb") as fh:
        decoded = {ch.topic: d for _, ch, _, d in
                   make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages()}
    cut = next(m for m in decoded["/cam/toolpath"].markers if m.ns == "02 finish raster" and m.id == 0)
    np.testing.assert_array_equal(pts(cut), segments_of(job.operations[1], C) / MM_PER_M)


def test_heightfield_full_grid_is_two_upward_triangles_per_cell() -> None:
    xs, ys = np.linspace(0, 10, 11), np.linspace(0, 5, 6)
    z = -np.add.outer(ys, xs) * 0.1
    v, f = heightfield_mesh(xs, ys, z)
    assert f.shape == (2 * 10 * 5, 3) and len(v) == 11 * 6
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    normals = np.cross(b - a, c - a)
    assert (normals[:, 2] > 0).all()
    np.testing.assert_allclose(np.abs(normals[:, 2]).sum() / 2, 10 * 5)  # covers the area once
    # Vertices sit on the grid with their heights.
    i, j = np.rint(v[:, 0]).astype(int), np.rint(v[:, 1]).astype(int)
    np.testing.assert_array_equal(v[:, 2], z[j, i])


def test_heightfield_decreasing_axes_still_face_up() -> None:
    xs, ys = np.linspace(10, 0, 6), np.linspace(0, 5, 4)
    v, f = heightfield_mesh(xs, ys, np.zeros((4, 6)))
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert (n[:, 2] > 0).all()


@settings(max_examples=40, deadline=None)
@given(hnp.arrays(np.bool_, st.tuples(st.integers(2, 12), st.integers(2, 12))))
def test_heightfield_skips_cells_without_material(holes: np.ndarray) -> None:
    ny, nx = holes.shape
    z = np.where(holes, -np.inf, 1.0)
    v, f = heightfield_mesh(np.arange(nx, dtype=float), np.arange(ny, dtype=float), z)
    assert np.isfinite(v).all()
    assert f.size == 0 or (f.min() >= 0 and f.max() < len(v))
    # Exactly the triangles whose three corners have material.
    full = np.isfinite(z)
    q = full[:-1, :-1] & full[:-1, 1:] & full[1:, 1:]
    r = full[:-1, :-1] & full[1:, 1:] & full[1:, :-1]
    assert len(f) == int(q.sum() + r.sum())


def test_heightfield_decimates_and_keeps_outline() -> None:
    xs, ys = np.linspace(0, 100, 1001), np.linspace(0, 80, 801)
    z = np.sin(xs)[None, :] * np.cos(ys)[:, None]
    v, f = heightfield_mesh(xs, ys, z, max_triangles=10_000)
    assert 5_000 < len(f) <= 10_000
    np.testing.assert_array_equal(v[:, :2].min(axis=0), [0, 0])
    np.testing.assert_array_equal(v[:, :2].max(axis=0), [100, 80])


def test_heightfield_shape_mismatch_is_an_error() -> None:
    with pytest.raises(McapError):
        heightfield_mesh(np.arange(3.0), np.arange(4.0), np.zeros((3, 4)))
