"""The test gallery of pictures in real light: the sample parts at seeded poses under issue 33's conditions.

The pictures are drawn by :func:`vision.lit.render_lit`, a ray caster independent of
:mod:`vision.render` (brushed and polished aluminium, self- and cast shadows, a satin tray,
vignetting, defocus, auto-exposure, noise); see that module. :func:`gallery_scene` draws one
seeded picture of one sample part (or one of :data:`OWN_PARTS`) in one of :data:`CONDITIONS`,
with the truth.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import trimesh

from vision.camera import CameraModel
from vision.lit import CONDITIONS, Material, key_light, metal, render_lit
from vision.locate import Footprint, footprint_from_mesh, mm_to_m
from vision.station import CameraStation, station_above

ROOT = Path(__file__).resolve().parents[2]
SAMPLE_PARTS = ("bracket", "stepped_wall", "plate_bosses", "dome_mould")
#: Shapes beyond the samples, from the parts gallery (tests/gallery/parts.py): an L standing on its
#: long leg (a 48 mm upright far above the tray, a long shadow, an outline whose turn its upright tells)
#: and a hexagonal boss with a bore on a round-cornered base (a freeform-cornered outline).
OWN_PARTS = ("l_bracket", "hex_boss")
#: Height of the cell's camera over the out-tray [m] (factory.cellcameras.CAMERA_HEIGHT_M).
CAMERA_HEIGHT_M = 0.5
TRAY_Z = 0.78


@dataclass(frozen=True)
class LitScene:
    """One rendered picture and where the part really is.

    Attributes
    ----------
    image : (h, w) uint8
    x, y : float
        The part's footprint centroid on the tray [m].
    yaw : float
        The part's turn about z [rad].
    symmetry : int
        Turns of the whole mesh (not only its footprint) that map it onto itself (1, 2 or 4).
    """

    image: np.ndarray
    x: float
    y: float
    yaw: float
    symmetry: int


@lru_cache(maxsize=None)
def sample_mesh(name: str) -> tuple[trimesh.Trimesh, Footprint, int]:
    """A sample part's (or one of :data:`OWN_PARTS`') mesh [mm], its footprint and its mesh symmetry order."""
    if name in OWN_PARTS:
        from tests.gallery import parts as gallery  # manifold3d builds them; only the own shapes need it

        mesh = next(p for p in gallery.PARTS if p.name == name).make()
    else:
        mesh = trimesh.load(ROOT / "samples" / f"{name}.stl")
    return mesh, footprint_from_mesh(mesh.vertices, mesh.faces, source=name), mesh_symmetry(mesh)


def mesh_symmetry(mesh: trimesh.Trimesh) -> int:
    """Largest of 4, 2, 1 whose turn about the footprint's vertical centre axis maps the mesh onto itself."""
    fp = footprint_from_mesh(mesh.vertices, mesh.faces)
    pts = mesh.sample(3000, seed=0) if "seed" in mesh.sample.__code__.co_varnames else mesh.sample(3000)
    centre = np.r_[fp.centroid * 1e3, 0.0]
    for n in (4, 2):
        a = 2 * np.pi / n
        r = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        turned = (pts - centre) @ r.T + centre
        _, dist, _ = trimesh.proximity.closest_point(mesh, turned)
        if np.percentile(dist, 99) < 0.05:
            return n
    return 1


def cell_station(camera: CameraModel | None = None) -> CameraStation:
    """The sample cell's out-tray camera: ``fixtures/camera.yaml`` 0.5 m straight above the tray."""
    camera = camera or CameraModel.read(ROOT / "fixtures" / "camera.yaml")
    return station_above(camera, np.array([0.05, 0.40, TRAY_Z]), CAMERA_HEIGHT_M)


def _placed(mesh_mm: trimesh.Trimesh, fp: Footprint, x: float, y: float, yaw: float, z: float
            ) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The mesh in metres with its footprint centroid at (x, y) on the tray, turned by yaw; and its frame."""
    c, s = np.cos(yaw), np.sin(yaw)
    t = np.eye(4)
    t[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    t[:3, 3] = np.array([x, y, z]) - t[:3, :3] @ np.r_[fp.centroid, fp.zmin]
    m = trimesh.Trimesh(mm_to_m(mesh_mm.vertices), mesh_mm.faces, process=False)
    m.apply_transform(t)
    return m, t


#: Where parts are put: within this of the point under the camera, in x and y [m].
SPREAD_M = (0.13, 0.09)


def gallery_scene(station: CameraStation, part: str, condition: str, seed: int, *,
                  supersample: int = 2, shown: trimesh.Trimesh | None = None) -> LitScene:
    """One seeded picture of a sample part at a random pose under one of :data:`CONDITIONS`.

    ``shown`` (a mesh [mm] in the sample's own frame, e.g. a defective copy of it) is drawn in the
    sample's place: same pose, light and noise as the sample's picture of that seed.
    """
    cond = CONDITIONS[condition]
    parts = SAMPLE_PARTS + OWN_PARTS
    rng = np.random.default_rng([seed, parts.index(part) if part in parts else 9,
                                 list(CONDITIONS).index(condition)])
    mesh, fp, symmetry = sample_mesh(part)
    mesh = mesh if shown is None else shown
    centre = station.camera_pose[:2, 3]
    x, y = centre + rng.uniform(-1, 1, 2) * SPREAD_M
    yaw = rng.uniform(-np.pi, np.pi)
    placed, frame = _placed(mesh, fp, x, y, yaw, station.plane_z)
    meshes = [(placed, metal(cond, frame))]
    if cond.distractor:
        size = rng.uniform([0.05, 0.035, 0.02], [0.08, 0.06, 0.045])
        for _ in range(200):
            a = rng.uniform(0, 2 * np.pi)
            bx, by = np.array([x, y]) + 0.115 * np.array([np.cos(a), np.sin(a)])
            if abs(bx - centre[0]) < SPREAD_M[0] + 0.04 and abs(by - centre[1]) < SPREAD_M[1] + 0.04:
                break
        box = trimesh.creation.box(size)
        bt = np.eye(4)
        byaw = rng.uniform(-np.pi, np.pi)
        bt[:3, :3] = [[np.cos(byaw), -np.sin(byaw), 0], [np.sin(byaw), np.cos(byaw), 0], [0, 0, 1]]
        bt[:3, 3] = [bx, by, station.plane_z + size[2] / 2]
        box.apply_transform(bt)
        meshes.append((box, Material(albedo=0.7, brushed=0.0, specular=0.05, shininess=5.0, frame=bt)))
    # Under glare: where the top face mirrors the key light into the camera.
    light = key_light(cond, rng, np.array([x, y, station.plane_z]), station.camera_pose[:3, 3])
    image = render_lit(station, meshes, cond, light, rng, supersample=supersample)
    return LitScene(image=image, x=float(x), y=float(y), yaw=float(yaw), symmetry=symmetry)
