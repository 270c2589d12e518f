"""The tunables of an inspection (:func:`vision.inspect.inspect_part`), below both the outline's rules
(:mod:`vision.inspect`) and the features' (:mod:`vision.inspect_features`), which read them."""

from __future__ import annotations

from dataclasses import dataclass

from vision.locate import LocateOptions


@dataclass(frozen=True)
class InspectOptions:
    """Tunables of :func:`vision.inspect.inspect_part`.

    Attributes
    ----------
    tolerance : float
        Largest deviation of a window of the outline, or of a feature, that passes [m].
    reach : float
        How far out along each outline edge's normal extra material is looked for [m]; a feature
        whose edges are absent counts as off by this much.
    depth : float
        How far in along each outline edge's normal missing material is looked for [m].
    window : float
        Length of outline over which the deviation is a median [m].
    min_feature_found : float
        Least share of a feature's visible edges the picture must show (0..1); below it the
        feature is missing.
    min_feature_edges : int
        Features with fewer visible edge samples (about a millimetre each) are too small to judge.
    min_whole_found : float
        Share of all a feature's visible edges (not only its creases with a wall turned to the
        camera) the picture shows from which it is there whatever its walls show (0..1): on the
        benchmark's pictures features that are there show 0.39-1, features left out up to 0.28.
    judge_from_above : bool
        Judge a feature with too few creases beside a wall turned to the camera (a boss, a thin
        wall seen from straight above) by all its edges. In real light its wall's shading and
        shadow show it (bosses there 0.39-1 of their edges, left out 0-0.03 on the benchmark; no
        good part rejected for it on seeds 0-1 and 8-9), so a camera's picture is judged so by
        default. With flat shading (the exact renderer of :mod:`vision.render`, the simulated
        cell's pictures) its top and the face it stands on look alike and a good boss shows 0.11
        of its edges: such pictures are judged with it off (:func:`vision.station.inspect_shot`),
        where a boss under the camera is not judged at all.
    min_seen : float
        Least share of the outline, and of each feature's edges, the picture must let be judged
        (0..1); below it (glare, an edge lost in shadow) the part is refused, not passed.
    locate : LocateOptions
        How the parts are located, with locate's refusals; a smaller share of all edges found than
        locate asks for by default, since a defect (a boss not there) takes edges away and must be
        judged, not refused (wrong poses reach 0.49 on locate's gallery, only when the outline's own
        checks let them through); not refined (:attr:`vision.locate.LocateOptions.refine`): the
        depths of its defects were measured and bounded at the pose fitted to all the edges.
    """

    tolerance: float = 0.7e-3
    reach: float = 3e-3
    depth: float = 25e-3
    window: float = 8e-3
    min_feature_found: float = 0.3
    min_feature_edges: int = 12
    min_whole_found: float = 0.45
    judge_from_above: bool = True
    min_seen: float = 0.5
    locate: LocateOptions = LocateOptions(min_found=0.35, refine=False)
