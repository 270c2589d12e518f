"""Edges the camera cannot see are unknown to ``inspect``, not missing (:mod:`vision.inspect_view`).

Pictures from tests/vision/lit.py of good parts that main rejected (benchmarks/inspect_real_light.py,
2026-11-29): an edge behind the part's own thin wall, and a feature beyond the picture's border.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.vision.lit import cell_station, gallery_scene, sample_mesh
from vision.camera import CameraModel
from vision.inspect import inspect_part
from vision.inspect_view import FRAME_PX, in_picture

ROOT = Path(__file__).resolve().parents[2]
FOUND_M = 1.5e-3


def inspected(station, condition: str, part: str, seed: int, supersample: int = 2):
    """The picture's truth and the one inspection of the good part in it."""
    scene = gallery_scene(station, part, condition, seed, supersample=supersample)
    mesh, footprint, _ = sample_mesh(part)
    (result,) = inspect_part(scene.image, station.camera, station.camera_pose, footprint, mesh.vertices,
                             mesh.faces, station.plane_z)
    assert np.hypot(result.part.x - scene.x, result.part.y - scene.y) <= FOUND_M
    return scene, result


@pytest.fixture(scope="module")
def station_5mp():
    return cell_station(CameraModel.read(ROOT / "fixtures" / "camera_5mp.yaml"))


def test_an_edge_behind_the_parts_own_wall_is_not_judged():
    """A good stepped wall in glare, off the camera's axis: its thin wall's white top, 20 mm above
    the step and 5 mm in from its rim, stands between the rim and the camera and shows 1.6 px beyond
    it. Main read that as 0.86 mm of extra material and rejected the part."""
    _, result = inspected(cell_station(), "glare", "stepped_wall", 1)
    assert result.passed and not result.refusal, result.to_dict()


def test_a_feature_beyond_the_picture_is_refused_not_missing(station_5mp):
    """A good dome mould at the 5 MP picture's left border: a hole lies beyond it, and the outline
    there reads the border's pixels. Main rejected it (a hole missing, the outline 1.2 mm out); the
    picture cannot tell: refused, with the reason, and what it shows is within the tolerance."""
    # one ray a pixel, as benchmarks/inspect_real_light.py renders the 5 MP camera (four took 6.6 GB)
    _, result = inspected(station_5mp, "diffuse", "dome_mould", 1, supersample=1)
    assert not result.passed and "beyond the picture" in result.refusal, result.to_dict()
    assert not result.missing_features
    assert result.max_deviation <= result.tolerance


def test_only_samples_whose_search_lies_in_the_picture_are_in_it():
    """A sample counts as in the picture only with its own edge search inside: in the middle, yes;
    within the search's reach of a border along its normal, no; along the border, parallel, yes."""
    uv = np.array([[50.0, 50.0], [2.0, 50.0], [50.0, 2.0], [97.0, 50.0], [50.0, 97.0]])
    across = np.array([[1.0, 0.0], [1.0, 0.0], [1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    assert in_picture((100, 100), uv, across, 2.5).tolist() == [True, False, True, False, False]
