"""A top-view picture of a job's toolpaths, for people who would rather look than read."""

from __future__ import annotations

import numpy as np

from cadcam.faces import FLAT, KIND_NAMES, SHALLOW, STEEP, WALL, FaceClasses
from cadcam.model import Job, Motion

#: RGB per operation kind; rapids are drawn thin and red over everything.
KIND_COLOURS = {"roughing": (40, 90, 200), "waterline": (230, 140, 20), "raster": (40, 160, 70),
                "finishing": (150, 60, 170)}
RAPID_COLOUR = (210, 40, 40)
_OTHER = (120, 120, 120)
#: Pale RGB per face kind (:mod:`cadcam.faces`), drawn under the toolpaths.
FACE_COLOURS = {FLAT: (205, 222, 245), SHALLOW: (210, 240, 205), STEEP: (250, 225, 195), WALL: (90, 90, 90)}


def _runs(motion: np.ndarray) -> list[tuple[int, int, bool]]:
    """``(first, last, is_rapid)`` point-index ranges of consecutive moves of one sort."""
    rapid = motion[1:] == Motion.RAPID
    if not len(rapid):
        return []
    change = np.flatnonzero(np.diff(rapid.astype(np.int8))) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [len(rapid)]])
    # Move k goes from point k to point k + 1.
    return [(int(s), int(e), bool(rapid[s])) for s, e in zip(starts, ends)]


def toolpath_image(job: Job, width: int = 900, faces: FaceClasses | None = None) -> np.ndarray:
    """Top view (XY) of every operation over the stock outline, with a legend.

    Parameters
    ----------
    job : Job
    width : int
        Width of the drawing area [px]; the height follows the stock's aspect ratio.
    faces : FaceClasses, optional
        The part's faces by kind, drawn under the toolpaths (flats, shallow and steep
        freeform filled pale, walls as dark lines), with their legend.

    Returns
    -------
    (H, W, 3) uint8
        RGB picture; write it with :func:`factory.pictures.png_bytes`.
    """
    from PIL import Image, ImageDraw  # only the stages that draw pay for the import

    lo, hi = job.setup.stock_min[:2], job.setup.stock_max[:2]
    reach = max((op.tool.radius for op in job.operations), default=0.0)
    lo, hi = lo - reach - 1.0, hi + reach + 1.0  # the tool centre may run outside the stock
    scale = (width - 20) / float(hi[0] - lo[0])
    height = int(round((hi[1] - lo[1]) * scale)) + 20
    face_kinds = [] if faces is None else [k for k in FACE_COLOURS if (faces.kind == k).any()]
    legend_h = 22 * (len(job.operations) + 2 + len(face_kinds))
    img = Image.new("RGB", (width, height + legend_h), (255, 255, 255))
    draw = ImageDraw.Draw(img)

    def px(xy: np.ndarray) -> list[tuple[float, float]]:
        u = 10 + (xy[:, 0] - lo[0]) * scale
        v = 10 + (hi[1] - xy[:, 1]) * scale  # picture rows grow downwards, Y grows away from the operator
        return list(zip(u.tolist(), v.tolist()))

    s0 = px(np.array([job.setup.stock_min[:2], job.setup.stock_max[:2]]))
    draw.rectangle([s0[0][0], s0[1][1], s0[1][0], s0[0][1]], outline=(0, 0, 0), width=2)

    if faces is not None:
        for k in (FLAT, SHALLOW, STEEP):
            for tri in faces.triangles[faces.kind == k]:
                draw.polygon(px(tri[:, :2]), fill=FACE_COLOURS[k])
        for tri in faces.triangles[faces.kind == WALL]:
            draw.line(px(tri[[0, 1, 2, 0], :2]), fill=FACE_COLOURS[WALL], width=1)

    rapids = []
    for op in job.operations:
        colour = KIND_COLOURS.get(op.kind, _OTHER)
        for first, last, is_rapid in _runs(op.motion):
            pts = px(op.points[first:last + 1, :2])
            if is_rapid:
                rapids.append(pts)
            elif len(pts) > 1:
                draw.line(pts, fill=colour, width=1)
    for pts in rapids:
        draw.line(pts, fill=RAPID_COLOUR, width=1)

    y = height + 4
    entries = [(f"{op.name}: T{op.tool.number} {op.tool.name}", KIND_COLOURS.get(op.kind, _OTHER))
               for op in job.operations] + [("rapid", RAPID_COLOUR)]
    entries += [(f"face: {KIND_NAMES[k]}", FACE_COLOURS[k]) for k in face_kinds]
    for text, colour in entries:
        draw.rectangle([10, y + 4, 30, y + 14], fill=colour)
        draw.text((38, y + 2), text, fill=(0, 0, 0))
        y += 22
    draw.text((10, y + 2), f"{job.part_name}: top view, stock outline in black", fill=(0, 0, 0))
    return np.asarray(img, dtype=np.uint8).copy()
