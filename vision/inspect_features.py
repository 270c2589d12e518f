"""Inspection's rules for the features inside a part's outline: is each hole, boss, pocket there?

A feature (one set of connected mesh edges inside the outline, :attr:`vision.mesh_edges.MeshEdges.feature`)
is there when the picture shows enough of its edges where the mesh puts them, and more often than
the picture's texture alone shows an edge beside them (:func:`judge_features`). :mod:`vision.inspect`
finds the edges and judges the outline; this module reads only what it found
(:class:`SeenEdges`). Lengths in metres, image positions in pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import map_coordinates
from scipy.spatial import cKDTree

from vision.inspect_options import InspectOptions
from vision.mesh_edges import MeshEdges, yaw_rotation_3d

#: Beside an edge this far either way [px] (clear of the own window and its blur) the picture shows
#: how often an edge lies within ``vision.inspect.OWN_PX`` of a spot by chance: a low light grazing a
#: brushed face makes many (a missing hole's place at 5 MP finds 0.35 of its edges there, 0.34 beside them).
BESIDE_PX = 4.5
#: A feature is there when the picture shows its edges this much more often at their place than beside
#: them (0..1): features that are there show 0.17 or more beyond it on the cell camera's worst pictures
#: and 0.2 at 5 MP, the missing hole above 0.01.
BEYOND_CHANCE = 0.1
#: Each loop of a feature's creases (:attr:`vision.mesh_edges.MeshEdges.loop`) that the light lets be judged
#: shows at least this share of its edges where the mesh puts them when the feature is there (0..1). A
#: counterbored boss's through-hole not drilled, at the cell camera (0.82 mm a pixel), finds 0.30-0.32 of the
#: edges beside its walls turned to the camera on the counterbore's wall and floor edges 3 mm off, but its rim on
#: the counterbore's floor 0.04-0.16; the loops of features there read 0.32 or more at the cell camera and 0.54
#: at 5 MP, every cached good picture (benchmarks/README.md, feature27).
LOOP_SHOWS = 0.2
#: Why an edge sample is unknown, as a refusal names it.
HIDDEN_BY = {1: "clipped white (glare)", 2: "in deep shadow on both sides", 3: "beyond the picture or behind the part"}
#: A wall this turned to the camera (cosine with the view) shows beside its crease (unitless).
FACING_COS = 0.1
#: A through-hole's rim is judged from every side where no other feature's edge lies this close [px].
RIM_CLEAR_PX = 5.0
#: The mesh under a feature's middle lower than this is none: a through-hole [m].
THROUGH_M = 2e-4
#: A wall turned to the camera whose face spans this much in the picture [px] shows its middle, 2 px from
#: either edge, clear enough of the blur and of a clipped neighbour's spill to tell (below).
WALL_BAND_PX = 4.0
#: A feature's walls turned to the camera are not there when at least this share of their faces' middles
#: (those wide enough to tell) is clipped white (0..1): a wall stands upright and cannot mirror into the
#: camera the light its top and the face around it mirror; one that stands shows grey or dark there. In
#: the glare pictures of benchmarks/inspect_real_light.py (5 MP seeds 0-1; cell camera seeds 0, 1, 8, 9)
#: features that are there read 0 at 5 MP and up to 0.46 at the cell camera (its spill over a 4-6 px
#: band); a boss or a hole not there, 1.0.
WALL_WHITE = 0.9


@dataclass(frozen=True)
class Feature:
    """One set of connected mesh edges inside the outline (a hole, a boss, a pocket) as the picture shows it.

    Attributes
    ----------
    pixel : (float, float)
        Centre of its visible edges in the image [px].
    edges : int
        Visible edge samples judged (about one per millimetre of edge).
    found : float
        Share of them the picture shows within ``vision.inspect.OWN_PX`` (0..1).
    present : bool
        Whether the share reaches ``InspectOptions.min_feature_found``, and what the picture's texture
        alone shows beside the feature's edges by :data:`BEYOND_CHANCE`.
    """

    pixel: tuple[float, float]
    edges: int
    found: float
    present: bool


@dataclass(frozen=True, eq=False)
class SeenEdges:
    """A located part's visible mesh edge samples and what the picture shows of each: what its
    features are judged on.

    Attributes
    ----------
    model : MeshEdges
        The part's edges.
    pose : (3,) float
        Where the part was located: x, y [m] and yaw [rad].
    idx : (k,) int
        The samples of ``model`` visible at ``pose``.
    uv : (k, 2) float
        Where they are in the picture [px].
    own : (k,) bool
        The picture shows their edge where the mesh puts it (within ``vision.inspect.OWN_PX``).
    unknown : (k,) bool
        Their edge cannot show (glare, deep shadow, beyond the picture).
    cause : (k,) int
        Why: a key of :data:`HIDDEN_BY`, 0 where the edge can show.
    beside : (k, 2) float
        Whether the picture shows an edge :data:`BESIDE_PX` off each sample either way: 1.0 or 0.0,
        NaN where another expected edge lies near that spot (the edge there is that one's).
    top_glare : bool
        The part's top is in glare (a good share of its silhouette clipped white).
    clipped : (h, w) uint8
        The picture's pixels clipped white (1), the rest 0.
    """

    model: MeshEdges
    pose: np.ndarray
    idx: np.ndarray
    uv: np.ndarray
    own: np.ndarray
    unknown: np.ndarray
    cause: np.ndarray
    beside: np.ndarray
    top_glare: bool
    clipped: np.ndarray


def judge_features(seen: SeenEdges, options: InspectOptions) -> tuple[list[Feature], list[str]]:
    """The features inside the outline, and the refusals of those hidden in glare.

    A feature is judged by its creases with a wall turned to the camera: a step between two faces
    turned up, its wall seen edge-on or from behind, may show no edge at all (the faces alike).
    Seen from straight above (too few such creases: a boss or a thin wall under the camera) it is
    judged by all its visible edges with ``judge_from_above``, and by each loop of its creases on its
    own (:func:`_least_loop`); one whose edges mostly show where the mesh puts them
    (``min_whole_found``) is there whatever its walls turned to the camera show.
    An edge found where the mesh puts it is the feature's, glare or not (a filled hole, a boss not
    there, leave a flat face and no edge there): a feature whose edges show, counting those beside
    clipped pixels as not found, is there. A feature hidden in glare is missing when nothing of the
    part can be white over it: a through-hole shows the tray or its walls, never a clipped top, so
    white on both sides of its edges is material where the hole should be. A pocket's or a bore's
    floor, a boss's top, mirror the light as the top does: hidden, but a wall of the feature turned to
    the camera, seen wide enough, shows where it should stand (:func:`_walls_white`): white there, no
    wall stands (a boss not there, a hole not drilled), and the feature is missing; otherwise hidden,
    not judged.
    A feature's edges must show at their place more often than the picture shows edges beside them
    (:func:`_chance`) by :data:`BEYOND_CHANCE` (:func:`_shows`): a low light grazing a brushed top
    puts edges everywhere, where a hole not drilled finds a third of its edges. Judged by its walls, each
    loop of its creases the light lets be judged must show as well (:data:`LOOP_SHOWS`): a hole not drilled
    under a counterbore finds edges beside its walls on the counterbore's, and none on its own rim.
    """
    model, idx, uv, own, unknown = seen.model, seen.idx, seen.uv, seen.own, seen.unknown
    outline_features = set(model.feature[idx[model.outer[idx]]])
    facing = model.crease[idx] & _wall_facing(model, seen.pose, idx)
    features, refusals = [], []
    for f in np.unique(model.feature[idx]):
        mine = model.feature[idx] == f
        through = _through(model, f)
        # A through-hole's rim shows from every side: the top against the hole's dark inside
        # (straight down a hole its wall is seen edge-on, and the rim is all there is to judge),
        # unless another feature's edges lie near (a counterbore's wall and its shadow on the floor).
        rim = mine & model.crease[idx] & through & \
            (model.points[idx, 2] >= model.points[model.feature == f, 2].max() - THROUGH_M)
        if rim.any() and (~mine).any():
            rim[rim] = cKDTree(uv[~mine]).query(uv[rim])[0] > RIM_CLEAR_PX
        every = mine & (facing | rim)
        # All its edges the light does not hide: where the mesh puts a crease or a contour the
        # picture shows one for most of a feature that is there, and for almost none of one that is not.
        whole = mine & ~unknown
        if f in outline_features or mine.sum() < options.min_feature_edges:
            continue  # too small in the picture to judge, light or not
        if every.sum() < options.min_feature_edges and whole.sum() < options.min_feature_edges:
            # Big enough to judge, but the light hides it (a boss seen from above, its edges all beside a
            # clipped top): skipped, a boss not there would pass unseen (the held-out glare plate_bosses 8).
            refusals.append(_hidden(seen, mine, uv[mine].mean(axis=0)))
            continue
        # The picture's texture alone finds this share of the feature's edges (:data:`BESIDE_PX`).
        chance = _chance(seen.beside[whole | every], options.min_feature_edges)
        # ... counted only where the light leaves most of them to be judged (a thin wall's few edges
        # clear of a white top say nothing of the rest).
        told = whole.sum() >= max(options.min_feature_edges, options.min_seen * mine.sum())
        whole_found = float(own[whole].mean()) if told else 0.0
        if every.sum() < options.min_feature_edges:
            # Seen from straight above, its walls edge-on: a boss, a thin wall, judged by all its edges
            # (with flat shading its top and the face it stands on look alike: off for such pictures).
            if not options.judge_from_above:
                continue
            if not told:  # mostly hidden: its few edges clear of the light say nothing of the rest
                refusals.append(_hidden(seen, mine, uv[mine].mean(axis=0)))
                continue
            centre = uv[whole].mean(axis=0)
            # Each loop of its creases on its own: a counterbored boss's through-hole not drilled keeps
            # its rim's share from the counterbore's floor 3 mm off (0.43-0.46), while its foot, where
            # the tray shows through, shows 0.17-0.20 (one there: 0.94-0.97; the loops of features
            # there judged so read 0.41 or more in diffuse, dim and low light, seeds 8-9).
            found = min(whole_found, _least_loop(model, idx, own, whole, options))
            features.append(Feature(pixel=(float(centre[0]), float(centre[1])), edges=int(whole.sum()),
                                    found=found, present=_shows(found, chance, options.min_feature_found)))
            continue
        on = every & ~unknown
        centre = uv[every].mean(axis=0)
        pixel = (float(centre[0]), float(centre[1]))
        anywhere = float(own[every].mean())
        if anywhere >= options.min_feature_found or whole_found >= options.min_whole_found:
            # A wall turned to the camera may show little against its floor (dim light, a shadow in
            # a counterbore) while the rest of the feature's edges are all there: the least share
            # was met above (by its walls or by all its edges), so only the texture's is asked ...
            found = max(anywhere, whole_found)
            # ... and that each loop of its creases the light lets be judged shows at all (:data:`LOOP_SHOWS`).
            least = _least_loop(model, idx, own, whole, options) if told else 1.0
            features.append(Feature(pixel=pixel, edges=int(every.sum()), found=found if least >= LOOP_SHOWS else least,
                                    present=_shows(found, chance, 0.0) and least >= LOOP_SHOWS))
        elif on.sum() >= options.min_seen * every.sum():
            share = float(own[on].mean())
            features.append(Feature(pixel=pixel, edges=int(on.sum()), found=share,
                                    present=_shows(share, chance, options.min_feature_found)))
        elif seen.top_glare and (through or _walls_white(seen, every, f, options.min_feature_edges)):
            features.append(Feature(pixel=pixel, edges=int(every.sum()), found=anywhere, present=False))
        else:
            refusals.append(_hidden(seen, every, centre))
    return features, refusals


def _hidden(seen: SeenEdges, edges: np.ndarray, centre: np.ndarray) -> str:
    """The refusal of a feature the light hides: where it is (``centre`` (2,) [px]), and why its ``edges``
    (mask over the seen samples) cannot be read, by share of each cause."""
    why = ", ".join(f"{100 * np.mean(seen.cause[edges] == k):.0f} % {name}" for k, name in HIDDEN_BY.items()
                    if np.any(seen.cause[edges] == k))
    return (f"the feature at ({centre[0]:.0f}, {centre[1]:.0f}) px is hidden in glare or shadow, or beyond the "
            f"picture (of its edges: {why})")


def _shows(found: float, chance: float, least: float) -> bool:
    """Whether a feature whose edges the picture shows at their place for the share ``found`` (0..1)
    is there: at least ``least`` of them (0..1), and :data:`BEYOND_CHANCE` more than the texture
    alone shows beside them (``chance``, :func:`_chance`)."""
    return found >= max(least, chance + BEYOND_CHANCE)


def _chance(beside: np.ndarray, least: int) -> float:
    """The share of a feature's edges the picture's texture alone would show (0..1): of ``beside`` (k, 2)
    (1.0: an edge near the spot BESIDE_PX off the sample on that side, 0.0 none, NaN another expected
    edge's), the quieter side's share; 0 unless both sides have at least ``least`` spots told. One side
    alone cannot tell texture from a structure running beside the edge (the white band of a step's top
    in glare finds an edge beside every sample), and the texture is the same on both sides."""
    told = np.isfinite(beside).sum(axis=0)
    if (told < least).any():
        return 0.0
    return float(np.nanmean(beside, axis=0).min())


def _least_loop(model: MeshEdges, idx: np.ndarray, own: np.ndarray, whole: np.ndarray,
                options: InspectOptions) -> float:
    """The least share of its edges found over one feature's loops of creases (:attr:`MeshEdges.loop`)
    the light lets be judged, as a whole feature is (``whole`` (k,) bool its visible samples ``idx`` not
    hidden, ``own`` (k,) bool their edge found where expected); 1 when no loop can be judged.

    A foot (:attr:`vision.mesh_edges.MeshEdges.foot`) is not judged on its own: the face and the wall rising from it meet in a
    fold that soft light shades over a few pixels, not at a line, so the picture's edge lies pixels
    either side of it (a good boss's foot at 5 MP in diffuse light: 0.12 found within OWN_PX, its top's
    rim 0.56). A boss not there leaves its top's rim as bare as its foot; a through-hole's foot on the
    underside, where the tray shows through, is a rim, not a foot."""
    loops = model.loop[idx]
    feet = model.foot[idx]
    least = 1.0
    for loop in np.unique(loops[whole & (loops >= 0)]):
        mine = loops == loop
        told = mine & whole
        if feet[mine].mean() <= 0.5 and told.sum() >= max(options.min_feature_edges, options.min_seen * mine.sum()):
            least = min(least, float(own[told].mean()))
    return least


def _through(model: MeshEdges, feature: int) -> bool:
    """Whether a feature is a through-hole: its edges reach the part's underside and the mesh has
    no material under its middle (the tray shows through it; a counterbore over a hole has its own
    floor), from the height field (:func:`vision.shadow.height_field`)."""
    points = model.points[model.feature == feature]
    middle = points[:, :2].mean(axis=0)
    return bool(points[:, 2].min() < THROUGH_M and model.field.at(middle[None])[0] < THROUGH_M)


def _wall_facing(model: MeshEdges, p: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``(k,)`` bool: an edge sample borders a wall (a face within 60 deg of vertical) turned to the
    camera by at least :data:`FACING_COS` (its cosine with the view)."""
    r = yaw_rotation_3d(p[2])
    view = model.eye - model.world(p, model.points[idx])
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    facing = np.zeros(len(idx), bool)
    for n in (model.n1[idx] @ r.T, model.n2[idx] @ r.T):
        facing |= (np.abs(n[:, 2]) < 0.5) & (np.einsum("nj,nj->n", n, view) >= FACING_COS)
    return facing


def _walls_white(seen: SeenEdges, every: np.ndarray, feature: int, least: int) -> bool:
    """Whether feature ``feature``'s walls turned to the camera are clipped white where their faces
    should show (``every`` (k,) bool its samples beside such a wall): the middle of each wall's face,
    halfway between its top edge and the feature's lowest edge straight below, read in the picture
    where the face spans at least :data:`WALL_BAND_PX`; True when :data:`WALL_WHITE` of them are
    clipped, False too when fewer than ``least`` are wide enough to tell. A boss not there leaves the
    face around it, in glare as white as its top; a boss there shows its lit wall grey or dark."""
    model = seen.model
    heights = model.points[model.feature == feature, 2]
    top, foot = heights.max(), heights.min()
    rims = model.points[seen.idx[every]]
    rims = rims[rims[:, 2] >= top - THROUGH_M]  # the walls' top edges: each wall hangs straight below one
    if len(rims) < least:
        return False

    def seen_at(z: float) -> np.ndarray:
        return model.camera.project(model.world(seen.pose, np.column_stack([rims[:, :2], np.full(len(rims), z)])),
                                    model.rvec, model.tvec)

    at_top, middle = seen_at(top), seen_at(0.5 * (top + foot))
    wide = np.linalg.norm(seen_at(foot) - at_top, axis=1) >= WALL_BAND_PX
    if wide.sum() < least:
        return False
    white = map_coordinates(seen.clipped, [middle[wide, 1], middle[wide, 0]], order=0, mode="nearest") > 0
    return bool(white.mean() >= WALL_WHITE)
