"""A part's mesh as a camera sees it: the edges that can show in a picture, at their real heights.

Locating and inspecting both fit these edges to a picture's (:mod:`vision.locate`,
:mod:`vision.inspect`). Lengths are in metres, angles in radians, image positions in pixels.
"""

from __future__ import annotations

from functools import cached_property
from typing import Protocol

import cv2
import numpy as np
import shapely
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError, cKDTree

from factory.core.kept import KeptAnswers, content_key
from vision.camera import CameraModel
from vision.shadow import height_field


class PartMesh(Protocol):
    """What the edges are made from (:class:`vision.locate.Footprint`): the mesh [m], its
    footprint's centroid (2,) [m] and outline (k, 2) around it [m], and its lowest z [m]."""

    vertices: np.ndarray
    faces: np.ndarray
    centroid: np.ndarray
    zmin: float
    outline: np.ndarray


#: Spacing of the model's edge samples [m] (about a pixel at the cell camera's distance).
EDGE_SAMPLE_M = 8e-4
#: Edge samples closer than this to the footprint's outline (in x, y) are on the part's outline [m].
OUTER_M = 5e-4
#: Faces meeting at more than this make an edge a picture can show [deg].
CREASE_DEG = 25.0
#: Two parallel model edges closer than this in the picture make one edge there (the gradient's
#: smoothing and the optics' blur) (:meth:`MeshEdges.unresolved`) [px] ...
RESOLVE_PX = 3.5
#: ... when their image normals' |cosine| is above this (about 25 deg) (unitless) ...
RESOLVE_COS = 0.9
#: ... and one lies higher than the other by more than this [m].
RESOLVE_DZ_M = 1e-3
#: A crease is a wall's foot where the part stands this much higher this far behind the wall [m]
#: (two texels of the height field: clear of its rounding at the wall, well under any boss or step).
FOOT_M = 1e-3


#: The edge models last made (:func:`edge_model`), at most :data:`KEPT_MODELS`, by what the part's mesh holds
#: (its vertices, faces, outline, centroid and lowest z), the camera and its pose.
KEPT_MODELS = 8
_MODELS: KeptAnswers[tuple, MeshEdges] = KeptAnswers(kept=KEPT_MODELS)


def edge_model(part: PartMesh, camera: CameraModel, cam_base: np.ndarray, tray_z: float) -> MeshEdges:
    """The :class:`MeshEdges` of ``part`` seen by ``camera`` at ``cam_base`` over the tray at ``tray_z`` [m], made
    once for the same mesh, camera and pose: a cell locates and inspects the same part in picture after
    picture, and making the model (the mesh's creases, its height field; the feet inspection asks for)
    cost a tenth of a locate. The mesh is told by its contents, not its object: inspection makes its
    part anew from the vertices it is given, every picture."""
    mesh = tuple(content_key(np.asarray(a)) for a in (part.vertices, part.faces, part.outline, part.centroid))
    key = (mesh, float(part.zmin), np.asarray(camera.K).tobytes(), np.asarray(camera.dist).tobytes(),
           tuple(camera.image_size), np.asarray(cam_base, np.float64).tobytes(), float(tray_z))
    return _MODELS.get(key, lambda: MeshEdges(part, camera, cam_base, tray_z))


def yaw_rotation(yaw: float) -> np.ndarray:
    """The 2 x 2 rotation by ``yaw`` [rad] about z."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s], [s, c]])


def yaw_rotation_3d(yaw: float) -> np.ndarray:
    """The 3 x 3 rotation by ``yaw`` [rad] about z (:func:`yaw_rotation`, z kept)."""
    r = np.eye(3)
    r[:2, :2] = yaw_rotation(yaw)
    return r


def _components(pairs: np.ndarray, vertices: int, of: np.ndarray | None = None) -> np.ndarray:
    """The connected component of each edge in ``of`` (default ``pairs``; (m, 2) vertex indices) in the
    graph of the edges ``pairs`` (k, 2) over ``vertices`` vertices: ``(m,)`` int."""
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(vertices,) * 2)
    return connected_components(graph, directed=False)[1][(pairs if of is None else of)[:, 0]]


def _hull_points(vertices: np.ndarray) -> np.ndarray:
    """``(h, 3)`` the vertices (n, 3) [m] on their convex hull (all of them where it is flat): a hull drawn
    from its projections, or their shadows', is that of the whole mesh."""
    try:
        return vertices[ConvexHull(vertices).vertices]
    except QhullError:
        return vertices


class MeshEdges:
    """The mesh's edges that can show in a picture, sampled about every :data:`EDGE_SAMPLE_M`.

    Creases (faces meeting at more than :data:`CREASE_DEG`) that border a face turned to the
    camera, and contour edges (one face turned to the camera, the other away) of smooth surfaces:
    the top outline, steps, bosses, holes and the silhouette at their real heights.
    """

    def __init__(self, part: PartMesh, camera: CameraModel, cam_base: np.ndarray, tray_z: float):
        self.part = part  # what it was made from
        mesh = trimesh.Trimesh(np.asarray(part.vertices) - np.r_[part.centroid, part.zmin], part.faces,
                               process=True)
        adj = mesh.face_adjacency
        angle = mesh.face_adjacency_angles
        keep = angle > np.radians(1.0)  # coplanar triangles of one face never show their edge
        ends = mesh.vertices[mesh.face_adjacency_edges[keep]]
        length = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
        n = np.maximum(np.ceil(length / EDGE_SAMPLE_M), 1).astype(int)
        edge = np.repeat(np.arange(len(n)), n)
        t = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + 0.5) / n[edge]
        self.points = ends[edge, 0] + t[:, None] * (ends[edge, 1] - ends[edge, 0])
        self.direction = (ends[:, 1] - ends[:, 0])[edge] / np.maximum(length[edge, None], 1e-12)
        self.n1 = mesh.face_normals[adj[keep, 0]][edge]
        self.n2 = mesh.face_normals[adj[keep, 1]][edge]
        sharp = angle[keep] > np.radians(CREASE_DEG)
        self.crease = sharp[edge]
        # Edges that share vertices make one feature (a hole, a boss, the outline), for inspection.
        pairs = mesh.face_adjacency_edges[keep]
        self.feature = _components(pairs, len(mesh.vertices))[edge]
        # Creases alone that share vertices make one loop of a feature (a through-hole's rim, its foot
        # on the underside, a counterbore's floor, a boss's top): the facets of a round wall join them
        # into one feature, and inspection judges each loop on its own (-1: no crease).
        self.loop = np.where(self.crease, _components(pairs[sharp], len(mesh.vertices), pairs)[edge], -1)
        self.edge = edge  # the mesh edge each sample lies on
        # Edges on the footprint's outline (at any height) make the part's outline against the tray:
        # glare or a dim top may hide the edges inside it, never these.
        ring = shapely.LinearRing(part.outline)
        self.axes = np.linalg.eigh(part.outline.T @ part.outline)[1]  # the outline's main directions (columns)
        self.outer = shapely.distance(shapely.points(self.points[:, :2]), ring) < OUTER_M
        self.camera, self.tray_z = camera, tray_z
        self.rvec = cv2.Rodrigues(cam_base[:3, :3])[0].ravel()
        self.tvec = cam_base[:3, 3]
        self.eye = -cam_base[:3, :3].T @ cam_base[:3, 3]
        self.field = height_field(mesh.vertices, mesh.faces)  # for the light and the shadows it casts
        self.hull_points = _hull_points(np.asarray(mesh.vertices))  # for the shadow's hull (vision.stray_edges)
        # Each face normal's reach to its sample, n . point: a face is turned to the eye e (part frame) where
        # n . e > n . point, one product per sample at any pose (:meth:`visible`).
        self.reach1 = np.einsum("nj,nj->n", self.n1, self.points)
        self.reach2 = np.einsum("nj,nj->n", self.n2, self.points)
        self._turned: dict[tuple[int, int], bool] = {}

    @cached_property
    def foot(self) -> np.ndarray:
        """``(n,)`` bool, read-only: the samples at the foot of a wall, a concave crease where a face turned up
        meets a wall rising from it (a boss's foot, a pocket's floor), from the height field: behind the
        wall (against its normal) the part stands at least :data:`FOOT_M` above the crease, :data:`FOOT_M`
        off it. Soft light shades such a fold over a few pixels, not at a line (:mod:`vision.inspect` does
        not judge a loop of them on its own). Of the mesh alone: made once, when first asked."""
        wall = np.where((self.n1[:, 2] > 0.5)[:, None], self.n2, self.n1)
        across = wall[:, :2] / np.maximum(np.linalg.norm(wall[:, :2], axis=1, keepdims=True), 1e-12)
        up = (np.maximum(self.n1[:, 2], self.n2[:, 2]) > 0.5) & (np.abs(wall[:, 2]) < 0.5)
        behind = self.field.at(self.points[:, :2] - FOOT_M * across)
        feet = up & (behind > self.points[:, 2] + FOOT_M)
        feet.flags.writeable = False
        return feet

    def same_turned(self, k: int, symmetry: int) -> bool:
        """Whether the mesh's edges turned by ``k`` of ``symmetry`` turns about the footprint's centroid
        fall on its own edges (within :data:`OUTER_M`): a symmetry of the mesh, not only of its outline."""
        if (k, symmetry) not in self._turned:  # a tree over every sample: asked per rival turn, made once
            r = yaw_rotation_3d(2 * np.pi * k / symmetry)
            d, _ = cKDTree(self.points).query(self.points @ r.T)
            self._turned[k, symmetry] = bool(np.quantile(d, 0.95) < OUTER_M)
        return self._turned[k, symmetry]

    def world(self, p: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Mesh points (centroid/zmin frame) placed at pose ``p = (x, y, yaw)`` [m, rad]."""
        return points @ yaw_rotation_3d(p[2]).T + np.array([p[0], p[1], self.tray_z])

    def visible(self, p: np.ndarray) -> np.ndarray:
        """Indices of the sample points that can show at pose ``p``."""
        eye, _ = self.in_part_frame(p, np.zeros(3))
        f1 = self.n1 @ eye > self.reach1
        f2 = self.n2 @ eye > self.reach2
        return np.flatnonzero((self.crease & (f1 | f2)) | (f1 != f2))

    def unresolved(self, uv: np.ndarray, normal: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """``(k,)`` bool over the visible samples ``idx`` (their pixels ``uv`` and image normals ``normal``,
        :meth:`project`): those a higher visible edge runs beside within :data:`RESOLVE_PX`, parallel.

        Two such edges make one edge in the picture (the blur is about as wide), and a sample takes the
        nearest edge: the foot of a wall seen nearly edge-on takes its top's crease, a wall's width off.
        Under glare the clipped top blooms over the thin wall and the crease is all there is; a
        dome mould 117 mm off the camera's axis was fitted 1.7 mm outward by its feet alone. The
        higher edge (the top face's, lit and facing the camera) is the one the picture shows, so the
        fit leaves the lower out. The judgement keeps them (missed when the picture has one edge there):
        left out, a stepped wall slid 12 mm along itself beside a box found 0.58 of its edges, not 0.46.
        """
        return self.beside(uv, normal, idx) >= 0

    def beside(self, uv: np.ndarray, normal: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """``(k,)`` int over the visible samples ``idx`` (as :meth:`unresolved`): for each, the position (in
        ``idx``) of the nearest higher parallel visible sample within :data:`RESOLVE_PX` in the picture,
        or -1 where there is none (the sample is resolved)."""
        partner = np.full(len(idx), -1)
        if len(idx) == 0:
            return partner
        z = self.points[idx, 2]
        pairs = cKDTree(uv).query_pairs(RESOLVE_PX, output_type="ndarray")
        if len(pairs) == 0:
            return partner
        i, j = pairs[:, 0], pairs[:, 1]
        parallel = np.abs(np.einsum("nj,nj->n", normal[i], normal[j])) > RESOLVE_COS
        up, down = parallel & (z[j] > z[i] + RESOLVE_DZ_M), parallel & (z[i] > z[j] + RESOLVE_DZ_M)
        lower, higher = np.r_[i[up], j[down]], np.r_[j[up], i[down]]
        # Written farthest first, so the nearest higher one is written last and stays.
        order = np.argsort(-np.linalg.norm(uv[lower] - uv[higher], axis=1), kind="stable")
        partner[lower[order]] = higher[order]
        return partner

    def feet_width(self, p: np.ndarray) -> float:
        """How wide the walls whose feet lie beside their tops (:meth:`beside`) look at pose ``p``: the feet's
        distances from their tops across the edge, summed, per visible outline sample [px]. Stacked
        walls (a plate and its bosses) count each foot."""
        idx = self.visible(p)
        uv, normal = self.project(p, idx)
        partner = self.beside(uv, normal, idx)
        foot = np.flatnonzero(partner >= 0)
        top = partner[foot]
        width = np.abs(np.einsum("nj,nj->n", uv[foot] - uv[top], normal[top]))
        return float(width.sum()) / max(int(self.outer[idx].sum()), 1)

    def placed(self, p: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(k, 2)`` pixel positions of part-frame ``points`` (k, 3) [m] at pose ``p`` and ``(k, 2, 3)`` their
        derivatives by the pose's x, y [px/m] and yaw [px/rad], for the edge fit's Jacobian."""
        w = self.world(p, points)
        uv, by_point = self.camera.project_with_jacobian(w, self.rvec, self.tvec)
        # d(world)/d(x, y, yaw): the unit x and y, and the point's lever about the pose turned a right angle.
        lever = np.zeros((len(w), 3, 3))
        lever[:, 0, 0] = lever[:, 1, 1] = 1.0
        lever[:, 0, 2], lever[:, 1, 2] = -(w[:, 1] - p[1]), w[:, 0] - p[0]
        return uv, by_point @ lever

    def pixels(self, p: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(k, 2)`` pixel positions of part-frame ``points`` (k, 3) [m] at pose ``p`` and ``(k, 2, 3)`` their
        derivatives by the points' part-frame coordinates [px/m]."""
        uv, by_point = self.camera.project_with_jacobian(self.world(p, points), self.rvec, self.tvec)
        return uv, by_point @ yaw_rotation_3d(p[2])

    def project(self, p: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(k, 2)`` pixel positions of the sample points ``idx`` at pose ``p`` and their unit image normals."""
        return self.image_of(p, self.points[idx], self.direction[idx])

    def image_of(self, p: np.ndarray, points: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(k, 2)`` pixel positions of part-frame ``points`` (k, 3) [m] at pose ``p`` and the unit image
        normals of lines through them along ``direction`` (k, 3)."""
        w = self.world(p, points)
        r = np.eye(3)
        r[:2, :2] = yaw_rotation(p[2])
        ahead = w + 1e-4 * (direction @ r.T)
        uv = self.camera.project(np.vstack([w, ahead]), self.rvec, self.tvec)
        k = len(points)
        tangent = uv[k:] - uv[:k]
        normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        return uv[:k], normal

    def in_part_frame(self, p: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The camera's eye (3,) [m] and a base-frame ``direction`` (3,) in the part's frame at pose ``p``."""
        r = np.eye(3)
        r[:2, :2] = yaw_rotation(p[2])
        return (self.eye - np.array([p[0], p[1], self.tray_z])) @ r, np.asarray(direction) @ r
