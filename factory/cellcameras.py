"""The cell's two fixed cameras, over the rack and over the out-tray, and the pictures they take of a part.

:func:`cell_stations` puts the cell camera file's camera :data:`CAMERA_HEIGHT_M` above the middle of
the rack's slots (one camera for every slot; :func:`rack_slots_seen` says which slots it sees a
blank in whole) and above out-tray slot (0, 0). :func:`camera_shots` takes, once per planned part, the
pictures the simulation shows and times its camera steps by: the blank located in the rack, the
empty slot, the good and the damaged part inspected in the out-tray (:mod:`vision.station` renders
each and runs the real vision on it); they are kept in the catalog beside the plan.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import trimesh

from factory.catalog import CatalogEntry
from factory.core.atomic import write_bytes, write_text
from robotprog.cell import Cell
from vision.camera import CameraModel
from vision.render import render_mesh
from vision.report import bgr_png_bytes
from vision.station import CameraShot, CameraStation, inspect_shot, locate_shot, station_above

log = logging.getLogger(__name__)

#: Height of the fixed cameras above the rack and the out-tray [m].
CAMERA_HEIGHT_M = 0.5
#: Margin a blank keeps from the picture's edges for the rack camera to see it whole [px]: locate
#: needs the floor around it.
VIEW_MARGIN_PX = 8
#: Diffuse reflectance of the rack's floor under its camera (0..1): dark grey anodised, as a vision
#: cell puts a contrasting background under bright metal. The camera looks straight down on a blank
#: and sees no side of it, only its top; under a low key light that top and a floor as grey as the
#: out-tray's (:data:`vision.lit.TRAY_ALBEDO`) take the same light and differ by their albedo alone
#: (about 15 grey levels over two pixels, below locate's edge threshold), so the lit sides of the
#: top do not show and the blank is refused. Against this floor they show in every light.
RACK_FLOOR_ALBEDO = 0.25
SHOTS_FORMAT = "factory.camera-shots/1"


@dataclass(frozen=True)
class Shot:
    """One camera picture as logged: annotated PNG, detections, measured processing [s]."""

    png: bytes
    detections: list[dict[str, Any]]
    processing_s: float
    passed: bool


@dataclass(frozen=True)
class Stations:
    """The cell's two fixed cameras, and where the blank (in rack slot (0, 0), the plan's) and the
    finished part lie under them [m]."""

    rack: CameraStation
    tray: CameraStation
    rack_xy: tuple[float, float]
    tray_xy: tuple[float, float]


def rack_middle(cell: Cell) -> np.ndarray:
    """The middle of the rack's slots, at slot height (3,) [m]: between its first and last slot."""
    grid = cell.rack
    first, last = grid.slot_transform(0, 0), grid.slot_transform(grid.rows - 1, grid.columns - 1)
    return (first[:3, 3] + last[:3, 3]) / 2


def cell_stations(cell: Cell, camera: CameraModel) -> Stations:
    """A camera :data:`CAMERA_HEIGHT_M` above the middle of the rack's slots (its floor
    :data:`RACK_FLOOR_ALBEDO`) and one above out-tray slot (0, 0)."""
    rack = cell.rack.pose.xyz
    tray = cell.out_tray.pose.xyz
    return Stations(station_above(camera, rack_middle(cell), CAMERA_HEIGHT_M, surface_albedo=RACK_FLOOR_ALBEDO),
                    station_above(camera, np.asarray(tray, dtype=float), CAMERA_HEIGHT_M),
                    (float(rack[0]), float(rack[1])), (float(tray[0]), float(tray[1])))


def rack_slots_seen(stations: Stations, cell: Cell, size: np.ndarray, reach: float) -> frozenset[tuple[int, int]]:
    """The rack slots (row, column) in which the rack camera sees a blank of ``size`` (3,) [m] whole,
    its top's corners standing up to ``reach`` [m] off their place in any direction, at least
    :data:`VIEW_MARGIN_PX` inside the picture."""
    station = stations.rack
    w, h = station.camera.image_size
    t = station.world_to_camera
    rvec = cv2.Rodrigues(np.asarray(t[:3, :3], dtype=np.float64))[0].reshape(3)
    half = np.asarray(size[:2], dtype=float) / 2 + reach
    corners = np.array([[sx * half[0], sy * half[1], float(size[2]), 1.0] for sx in (-1, 1) for sy in (-1, 1)])
    grid = cell.rack
    seen = set()
    for r in range(grid.rows):
        for c in range(grid.columns):
            world = (grid.slot_transform(r, c) @ corners.T).T[:, :3]
            uv = station.camera.project(world, rvec, t[:3, 3])
            inside = (uv >= VIEW_MARGIN_PX).all() and (uv[:, 0] <= w - 1 - VIEW_MARGIN_PX).all() and \
                (uv[:, 1] <= h - 1 - VIEW_MARGIN_PX).all()
            if inside:
                seen.add((r, c))
    return frozenset(seen)


def _empty_frame(station: CameraStation) -> np.ndarray:
    grey = render_mesh(station.rays, station.world_to_camera, np.zeros((0, 3)), np.zeros((0, 3), np.int64),
                       plane_z=station.plane_z, noise_sigma=2.0, seed=0)
    canvas = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
    cv2.putText(canvas, "NO STOCK FOUND", (20, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.0, (0, 0, 255), 2, cv2.LINE_AA)
    return canvas


def _rack_view(stations: Stations) -> list[float]:
    """Where the rack camera stands [m, rounded to a micrometre]: shots taken from elsewhere are taken again."""
    return [round(float(v), 6) for v in stations.rack.camera_pose[:3, 3]]


def _shot(shot: CameraShot) -> Shot:
    # rounded as the cache keeps it, so a fresh and a cached run time their camera steps alike
    return Shot(bgr_png_bytes(shot.annotated), list(shot.detections), round(float(shot.processing_s), 4),
                bool(shot.passed))


def camera_shots(entry: CatalogEntry, part_mesh: trimesh.Trimesh, stock_mm: np.ndarray, stations: Stations,
                 camera_sha256: str) -> dict[str, Shot]:
    """Locate (blank, empty slot) and inspect (good, damaged part) pictures for one part, kept in the
    catalog beside its plan (``PART.camera.json`` + PNGs) and reused while the camera is unchanged."""
    stem = Path(entry.summary["part"]).stem
    folder = entry.summary_path.parent
    index = folder / f"{stem}.camera.json"
    names = ("locate", "empty", "inspect", "reject")
    if index.is_file():
        try:
            doc = json.loads(index.read_text(encoding="utf-8"))
            if doc.get("format") == SHOTS_FORMAT and doc.get("key") == entry.key and \
                    doc.get("camera_sha256") == camera_sha256 and doc.get("rack_view") == _rack_view(stations):
                return {n: Shot((folder / doc["shots"][n]["png"]).read_bytes(), doc["shots"][n]["detections"],
                                doc["shots"][n]["processing_s"], doc["shots"][n]["passed"]) for n in names}
        except (OSError, ValueError, KeyError, TypeError):
            log.warning("%s: unreadable camera shots, taken again", index)
    blank = trimesh.creation.box(stock_mm)
    blank.apply_translation(np.asarray(stock_mm) / 2)
    v, f = np.asarray(part_mesh.vertices), np.asarray(part_mesh.faces)
    rx, ry = stations.rack_xy
    tx, ty = stations.tray_xy
    shots = {
        "locate": _shot(locate_shot(stations.rack, np.asarray(blank.vertices), np.asarray(blank.faces),
                                    (rx, ry, 0.0), seed=1)),
        "empty": Shot(bgr_png_bytes(_empty_frame(stations.rack)), [], 0.0, False),
        "inspect": _shot(inspect_shot(stations.tray, v, f, (tx, ty, 0.0), defect=False, seed=2)),
        "reject": _shot(inspect_shot(stations.tray, v, f, (tx, ty, 0.0), defect=True, seed=3)),
    }
    if not shots["locate"].passed:
        log.warning("%s: the rack camera did not locate the rendered blank within tolerance", stem)
    if not shots["inspect"].passed or shots["reject"].passed:
        log.warning("%s: inspection of the rendered parts disagrees with the truth (good %s, damaged %s)", stem,
                    "passed" if shots["inspect"].passed else "failed",
                    "passed" if shots["reject"].passed else "failed")
    doc = {"format": SHOTS_FORMAT, "key": entry.key, "camera_sha256": camera_sha256,
           "rack_view": _rack_view(stations), "shots": {}}
    for n, s in shots.items():
        png = f"{stem}.{n}.png"
        write_bytes(folder / png, s.png, overwrite=True)  # a stale cache is replaced
        doc["shots"][n] = {"png": png, "detections": s.detections, "processing_s": s.processing_s,
                           "passed": s.passed}
    write_text(index, json.dumps(doc, indent=2) + "\n", overwrite=True)
    return shots
