"""Top-view pictures for people who would rather look than read: a job's toolpaths, its setup, and the
stock a verified program leaves on the part (the deviation map)."""

from __future__ import annotations

import math

import numpy as np

from cadcam.faces import FLAT, KIND_NAMES, SHALLOW, STEEP, WALL, FaceClasses
from cadcam.model import Job, Motion, Setup
from cadcam.stock import Simulation
from cadcam.verify import VerifyReport

#: One RGB per tool, in the order the job first uses them (cycled past the last); drawn over pale faces.
TOOL_COLOURS = ((40, 90, 200), (230, 120, 20), (40, 150, 60), (150, 60, 170), (200, 40, 90), (20, 160, 170),
                (140, 100, 40), (90, 90, 230), (120, 160, 30), (60, 60, 60))
#: Rapids: thin and faint, drawn under the cuts so that they never hide the part or a cut.
RAPID_COLOUR = (245, 175, 175)
#: The work origin's mark.
ORIGIN_COLOUR = (220, 0, 0)
#: Pale RGB per face kind (:mod:`cadcam.faces`), drawn under the toolpaths.
FACE_COLOURS = {FLAT: (205, 222, 245), SHALLOW: (210, 240, 205), STEEP: (250, 225, 195), WALL: (90, 90, 90)}
#: Tick spacings the axes choose from [mm].
_TICKS = (1.0, 2.0, 5.0, 10.0, 20.0, 25.0, 50.0, 100.0, 200.0, 250.0, 500.0)


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


def tool_colours(job: Job) -> dict[int, tuple[int, int, int]]:
    """Tool number -> its RGB in the toolpath picture, in the order the job first uses the tools."""
    numbers = list(dict.fromkeys(op.tool.number for op in job.operations))
    return {n: TOOL_COLOURS[i % len(TOOL_COLOURS)] for i, n in enumerate(numbers)}


def toolpath_legend(job: Job) -> list[str]:
    """The legend's lines, one per tool: its number, name and the operations it cuts."""
    ops: dict[int, list[str]] = {}
    names: dict[int, str] = {}
    for op in job.operations:
        ops.setdefault(op.tool.number, []).append(op.name)
        names[op.tool.number] = op.tool.name
    return [f"T{n} {names[n]}: {', '.join(dict.fromkeys(ops[n]))}" for n in ops]


def tick_step(span: float, most: int = 10) -> float:
    """The smallest of 1, 2, 5, 10, ... mm that puts at most ``most`` ticks across ``span`` [mm]."""
    return next((t for t in _TICKS if span / t <= most), _TICKS[-1])


def toolpath_image(job: Job, width: int = 900, faces: FaceClasses | None = None) -> np.ndarray:
    """Top view (XY) of every operation over the stock outline, with axes in mm, a scale bar, the work
    origin and a legend of one colour per tool.

    Rapids are drawn thin and faint under the cuts; the part's faces (when given) pale under both.

    Parameters
    ----------
    job : Job
    width : int
        Width of the picture [px]; the height follows the stock's aspect ratio.
    faces : FaceClasses, optional
        The part's faces by kind, drawn under the toolpaths (flats, shallow and steep
        freeform filled pale, walls as dark lines), with their legend.

    Returns
    -------
    (H, W, 3) uint8
        RGB picture; write it with :func:`factory.pictures.png_bytes`.
    """
    from PIL import Image, ImageDraw  # only the stages that draw pay for the import

    setup = job.setup
    lo, hi = setup.stock_min[:2], setup.stock_max[:2]
    reach = max((op.tool.radius for op in job.operations), default=0.0)
    lo, hi = lo - reach - 1.0, hi + reach + 1.0  # the tool centre may run outside the stock
    left, right, top, bottom = 56, 14, 12, 44  # room for the Y labels, and the X labels and scale bar below
    scale = (width - left - right) / float(hi[0] - lo[0])
    height = int(round((hi[1] - lo[1]) * scale)) + top + bottom
    colours = tool_colours(job)
    face_kinds = [] if faces is None else [k for k in FACE_COLOURS if (faces.kind == k).any()]
    legend_h = 22 * (len(colours) + 3 + len(face_kinds))
    img = Image.new("RGB", (width, height + legend_h), (255, 255, 255))
    draw = ImageDraw.Draw(img)

    def px(xy: np.ndarray) -> list[tuple[float, float]]:
        u = left + (xy[:, 0] - lo[0]) * scale
        v = top + (hi[1] - xy[:, 1]) * scale  # picture rows grow downwards, Y grows away from the operator
        return list(zip(u.tolist(), v.tolist()))

    if faces is not None:  # each kind's corners in pixels at once: the same numbers as one triangle at a time
        for k in (FLAT, SHALLOW, STEEP):
            corners = px(faces.triangles[faces.kind == k][:, :, :2].reshape(-1, 2))
            for i in range(0, len(corners), 3):
                draw.polygon(corners[i:i + 3], fill=FACE_COLOURS[k])
        rings = px(faces.triangles[faces.kind == WALL][:, [0, 1, 2, 0], :2].reshape(-1, 2))
        for i in range(0, len(rings), 4):
            draw.line(rings[i:i + 4], fill=FACE_COLOURS[WALL], width=1)
    runs = [(op, first, last, is_rapid) for op in job.operations for first, last, is_rapid in _runs(op.motion)]
    for op, first, last, is_rapid in runs:  # rapids first: the cuts lie over them
        if is_rapid:
            draw.line(px(op.points[first:last + 1, :2]), fill=RAPID_COLOUR, width=1)
    for op, first, last, is_rapid in runs:
        pts = px(op.points[first:last + 1, :2])
        if not is_rapid and len(pts) > 1:
            draw.line(pts, fill=colours[op.tool.number], width=1)
    for op in job.operations:  # a drill cycle moves only along Z: its holes as circles of the drill's size
        if op.cycle is not None:
            r = op.tool.radius * scale
            for (u, v) in px(np.asarray(op.cycle.holes)[:, :2]):
                draw.ellipse([u - r, v - r, u + r, v + r], outline=colours[op.tool.number], width=2)
    s0 = px(np.array([setup.stock_min[:2], setup.stock_max[:2]]))
    draw.rectangle([s0[0][0], s0[1][1], s0[1][0], s0[0][1]], outline=(0, 0, 0), width=2)
    _axes(draw, px, lo, hi, height - bottom)
    _origin_and_scale(draw, px, left, height, float(hi[0] - lo[0]), scale)

    y = height + 4
    entries = [(text, colours[n]) for n, text in zip(colours, toolpath_legend(job))] + [("rapid", RAPID_COLOUR)]
    entries += [(f"face: {KIND_NAMES[k]}", FACE_COLOURS[k]) for k in face_kinds]
    for text, colour in entries:
        draw.rectangle([10, y + 4, 30, y + 14], fill=colour)
        draw.text((38, y + 2), text, fill=(0, 0, 0))
        y += 22
    draw.text((10, y + 2), f"{job.part_name}: top view [mm], work coordinates; stock outline in black, "
                           f"work origin X0 Y0 in red", fill=(0, 0, 0))
    return np.asarray(img, dtype=np.uint8).copy()


def _axes(draw, px, lo: np.ndarray, hi: np.ndarray, axis_v: float) -> None:
    """Ticks and labels in mm along the bottom (X) and the left (Y) of the drawing, at ``axis_v`` [px] and
    the drawing's left edge."""
    step = tick_step(float(max(hi - lo)))
    u_left = px(np.array([[lo[0], lo[1]]]))[0][0]
    draw.line([(u_left, px(np.array([[lo[0], hi[1]]]))[0][1]), (u_left, axis_v)], fill=(0, 0, 0))
    draw.line([(u_left, axis_v), (px(np.array([[hi[0], lo[1]]]))[0][0], axis_v)], fill=(0, 0, 0))
    for x in np.arange(math.ceil(lo[0] / step) * step, hi[0] + 1e-9, step):
        u = px(np.array([[x, lo[1]]]))[0][0]
        draw.line([(u, axis_v), (u, axis_v + 4)], fill=(0, 0, 0))
        draw.text((u - 8, axis_v + 5), f"{x:g}", fill=(0, 0, 0))
    for yv in np.arange(math.ceil(lo[1] / step) * step, hi[1] + 1e-9, step):
        v = px(np.array([[lo[0], yv]]))[0][1]
        draw.line([(u_left - 4, v), (u_left, v)], fill=(0, 0, 0))
        draw.text((u_left - 44, v - 6), f"{yv:g}".rjust(6), fill=(0, 0, 0))
    draw.text((u_left - 50, axis_v + 5), "X, Y mm", fill=(0, 0, 0))


def _origin_and_scale(draw, px, left: float, height: int, span: float, scale: float) -> None:
    """The work origin's cross and label, and a scale bar of a round length under the X axis."""
    (u, v), = px(np.array([[0.0, 0.0]]))
    draw.line([(u - 8, v), (u + 8, v)], fill=ORIGIN_COLOUR, width=2)
    draw.line([(u, v - 8), (u, v + 8)], fill=ORIGIN_COLOUR, width=2)
    draw.text((u + 5, v + 3), "X0 Y0", fill=ORIGIN_COLOUR)
    bar = tick_step(span, most=5)
    y = height - 12
    draw.rectangle([left, y, left + bar * scale, y + 4], fill=(0, 0, 0))
    draw.text((left + bar * scale + 6, y - 4), f"{bar:g} mm", fill=(0, 0, 0))


#: Colours of the setup picture.
_JAW_COLOUR = (150, 150, 160)
_PARALLELS_COLOUR = (190, 175, 120)
_PART_COLOUR = (60, 120, 200)
_FLOOR_COLOUR = (210, 40, 40)


def setup_image(setup: Setup, part_triangles: np.ndarray, title: str, width: int = 900) -> np.ndarray:
    """The part in the vise: a section across the jaws (Y right, Z up) beside a top view (XY).

    The stock is outlined in black, the part's silhouette filled blue, the jaws grey, the
    parallels tan, and op 1's floor (:attr:`Setup.floor_z`) a dashed red line: the tool
    never feeds below it, so the holding allowance under it stays for the vise.

    Parameters
    ----------
    setup : Setup
        With ``jaws`` (None: the stock and part alone are drawn).
    part_triangles : (m, 3, 3) float
        The part in work coordinates [mm].
    title : str
        Caption under the views.
    width : int
        Width of the picture [px].

    Returns
    -------
    (H, W, 3) uint8
        RGB picture; write it with :func:`factory.pictures.png_bytes`.
    """
    from PIL import Image, ImageDraw  # only the stages that draw pay for the import

    tri = np.asarray(part_triangles, dtype=np.float64).reshape(-1, 3, 3)
    boxes = tuple(setup.jaws or ())
    lo = np.min([setup.stock_min] + [b.lo for b in boxes], axis=0) - 2.0
    hi = np.max([setup.stock_max] + [b.hi for b in boxes], axis=0) + 2.0
    # section: Y across, Z up; top view: X across, Y up. One scale for both.
    span_w = (hi[1] - lo[1]) + (hi[0] - lo[0])
    scale = (width - 30) / float(span_w)
    panel_h = int(round(max(hi[2] - lo[2], hi[1] - lo[1]) * scale)) + 20
    caption_h = 22 * 4
    img = Image.new("RGB", (width, panel_h + caption_h), (255, 255, 255))
    draw = ImageDraw.Draw(img)
    left_w = (hi[1] - lo[1]) * scale

    def section(yz: np.ndarray) -> list[tuple[float, float]]:
        u = 10 + (yz[..., 0] - lo[1]) * scale
        v = 10 + (hi[2] - yz[..., 1]) * scale
        return list(zip(np.ravel(u).tolist(), np.ravel(v).tolist()))

    def top(xy: np.ndarray) -> list[tuple[float, float]]:
        u = 20 + left_w + (xy[..., 0] - lo[0]) * scale
        v = 10 + (hi[1] - xy[..., 1]) * scale
        return list(zip(np.ravel(u).tolist(), np.ravel(v).tolist()))

    def rect(to_px, a: np.ndarray, b: np.ndarray, **kw) -> None:
        (u0, v0), (u1, v1) = to_px(np.array([a, b]))
        draw.rectangle([min(u0, u1), min(v0, v1), max(u0, u1), max(v0, v1)], **kw)

    for b in boxes:
        fill = _PARALLELS_COLOUR if b.name == "parallels" else _JAW_COLOUR
        rect(section, b.lo[[1, 2]], b.hi[[1, 2]], fill=fill, outline=(80, 80, 80))
        if b.name != "parallels":
            rect(top, b.lo[:2], b.hi[:2], fill=fill, outline=(80, 80, 80))
    # the part's silhouettes: every triangle projected (Y, Z) and (X, Y), filled; the corners' pixels worked out
    # for all triangles at once (the same numbers as one triangle at a time: each is its own sum and product)
    sections, tops = section(tri[:, :, [1, 2]]), top(tri[:, :, :2])
    for k in range(0, 3 * len(tri), 3):
        draw.polygon(sections[k:k + 3], fill=_PART_COLOUR)
        draw.polygon(tops[k:k + 3], fill=_PART_COLOUR)
    rect(section, setup.stock_min[[1, 2]], setup.stock_max[[1, 2]], outline=(0, 0, 0), width=2)
    rect(top, setup.stock_min[:2], setup.stock_max[:2], outline=(0, 0, 0), width=2)
    # op 1's floor, dashed across the stock
    y0, y1 = float(setup.stock_min[1]), float(setup.stock_max[1])
    for ya in np.arange(y0, y1, 3.0):
        draw.line(section(np.array([[ya, setup.floor_z], [min(ya + 1.5, y1), setup.floor_z]])),
                  fill=_FLOOR_COLOUR, width=2)

    y = panel_h + 4
    held = float(setup.floor_z - setup.stock_min[2])
    lines = [f"{title}: op 1, the part in the vise (left: section across the jaws; right: top view)",
             f"stock {' x '.join(f'{v:g}' for v in np.round(setup.stock_size, 2))} mm; "
             f"op 1 cuts down to Z{setup.floor_z:.2f} (dashed red), leaving {held:.1f} mm held",
             "grey: jaws, tan: parallels" if boxes else "no vise known: jaws not drawn"]
    for text in lines:
        draw.text((10, y + 2), text, fill=(0, 0, 0))
        y += 22
    return np.asarray(img, dtype=np.uint8).copy()


_STOPS = np.array([0.0, 0.25, 0.5, 0.75, 1.0])
_COLOURS = np.array([[40, 70, 200], [0, 180, 220], [60, 185, 75], [240, 215, 40], [245, 130, 20]], dtype=np.float64)
_GOUGE = np.array([215, 25, 30], dtype=np.float64)
_NO_PART = np.array([70, 70, 70], dtype=np.float64)


def _colour(values: np.ndarray, vmax: float, tol: float) -> np.ndarray:
    """RGB (float) for remaining-stock values: blue on size, to orange at ``vmax``, red for gouges."""
    u = np.clip(np.nan_to_num(values, nan=0.0) / vmax, 0.0, 1.0)
    rgb = np.stack([np.interp(u, _STOPS, _COLOURS[:, c]) for c in range(3)], axis=-1)
    rgb[values < -tol] = _GOUGE
    rgb[np.isnan(values)] = _NO_PART
    return rgb


def deviation_image(sim: Simulation, report: VerifyReport, width: int = 640,
                    on_part: np.ndarray | None = None) -> np.ndarray:
    """A top view of the stock left on the part, with axes in mm, a scale bar, the work origin and a
    colour bar.

    Blue is on size, through cyan, green and yellow to orange at the largest remaining
    stock; red is a gouge deeper than the tolerance; grey is where there is no part. The
    deepest gouge is ringed in white, rapid crashes are marked with a magenta cross, every
    other fault with a square labelled with its kind, tool and first line. Y points up in
    the picture (away from the operator).

    Parameters
    ----------
    sim : Simulation
    report : VerifyReport
    width : int
        Approximate width of the map part of the picture [px].
    on_part : (ny, nx) bool or None
        Where the part's own surface lies: the colour scale runs to the 99th percentile of the stock
        left there, and more (there or elsewhere: a relief's uncut rim outside its boundary,
        :func:`cadcam.relief.surface_footprint`) shows in the top colour. None: every grid point
        with part under it.

    Returns
    -------
    (H, W, 3) uint8
        RGB picture; write it with :func:`factory.pictures.png_bytes`.
    """
    from PIL import Image, ImageDraw, ImageFont

    grid = sim.grid
    tol = report.gouge_tolerance
    on = np.isfinite(sim.part_top) if on_part is None else on_part & np.isfinite(sim.part_top)
    left = sim.remaining[on]
    left = left[np.isfinite(left)]
    most = float(left.max()) if len(left) else 0.0
    # The scale runs to the 99th percentile of what is left on the part, so a thin strip of deep
    # stock (a relief's edge the ball cannot reach) does not wash the rest out to one blue; more
    # shows in the top colour, labelled ">=". A few points of stock on a finished part still set it.
    top = float(np.percentile(left, 99.0)) if len(left) else 0.0
    vmax = top if top > max(tol, 1e-6) else most if most > max(tol, 1e-6) else 1.0
    rgb = _colour(sim.remaining, vmax, tol)[::-1]  # row 0 of the picture is the largest Y
    scale = max(1, width // max(grid.nx, grid.ny))
    step = max(1, math.ceil(max(grid.nx, grid.ny) / width))
    rgb = rgb[::step, ::step]
    rgb = np.repeat(np.repeat(rgb, scale, axis=0), scale, axis=1)
    px = scale / step  # picture pixels per grid point
    h, w = rgb.shape[:2]

    # left: room for the Y labels; below the map, the X labels and the scale bar (as toolpath_image)
    margin, left, axes_h, bar_w, label_w, caption_h = 12, 56, 44, 18, 150, 20
    H = max(margin + h + axes_h + caption_h, 260)
    W = max(left + w + margin + bar_w + label_w, left + 420)  # room for the caption
    canvas = np.full((H, W, 3), 255, dtype=np.uint8)
    canvas[margin:margin + h, left:left + w] = np.round(rgb).astype(np.uint8)

    # Colour bar: gouge band at the bottom, then 0 .. vmax upwards.
    bx = left + w + margin
    bar_h = H - 2 * margin - 40
    gouge_h = 14
    ramp_h = bar_h - gouge_h - 4
    vals = np.linspace(vmax, 0.0, ramp_h)
    canvas[margin:margin + ramp_h, bx:bx + bar_w] = np.round(_colour(vals, vmax, tol))[:, None, :].astype(np.uint8)
    gy = margin + ramp_h + 4
    canvas[gy:gy + gouge_h, bx:bx + bar_w] = _GOUGE.astype(np.uint8)
    ny_ = gy + gouge_h + 4
    canvas[ny_:ny_ + gouge_h, bx:bx + bar_w] = _NO_PART.astype(np.uint8)

    img = Image.fromarray(canvas)
    draw = ImageDraw.Draw(img)
    font = ImageFont.load_default()
    tx = bx + bar_w + 5
    for frac in (0.0, 0.5, 1.0):
        y = margin + int(round((1 - frac) * (ramp_h - 1)))
        draw.line([(bx + bar_w, y), (bx + bar_w + 3, y)], fill=(0, 0, 0))
        above = frac == 1.0 and vmax < max(most, report.remaining_max)  # more is left, shown in the top colour
        draw.text((tx, y - 6), f"{'>= ' if above else ''}{frac * vmax:.3f} mm", fill=(0, 0, 0), font=font)
    draw.text((tx, gy), f"gouge > {tol:g} mm", fill=(0, 0, 0), font=font)
    draw.text((tx, ny_), "no part", fill=(0, 0, 0), font=font)
    caption = f"remaining stock above the part, max gouge {report.max_gouge:.3f} mm"
    if report.rapid_crashes:
        caption += f", {len(report.rapid_crashes)} rapid crash(es)"
    others = [f.kind for f in report.faults if f.kind != "rapid"]
    if others:
        caption += ", " + ", ".join(sorted(set(others)))
    draw.text((margin, margin + h + axes_h + 2), caption, fill=(0, 0, 0), font=font)

    def to_px(x: float, y: float) -> tuple[float, float]:
        col = (x - grid.x0) / grid.cell
        row = (grid.ny - 1) - (y - grid.y0) / grid.cell
        return left + col * px + px / 2, margin + row * px + px / 2

    def xy_px(xy: np.ndarray) -> list[tuple[float, float]]:
        return [to_px(float(x), float(y)) for x, y in xy]

    # The map's edges in mm: each grid point is a square of one cell round it (the last one may be
    # cut by the step).
    y_top = grid.y0 + (grid.ny - 0.5) * grid.cell
    lo = np.array([grid.x0 - 0.5 * grid.cell, y_top - h / px * grid.cell])
    hi = np.array([grid.x0 + (w / px - 0.5) * grid.cell, y_top])
    _axes(draw, xy_px, lo, hi, margin + h)
    _origin_and_scale(draw, xy_px, left, margin + h + axes_h, float(hi[0] - lo[0]), px / grid.cell)

    _mark_faults(draw, report, to_px, font)
    return np.asarray(img, dtype=np.uint8).copy()


def _mark_faults(draw, report: VerifyReport, to_px, font) -> None:
    """The deepest gouge ringed in white, each rapid crash a magenta cross, every other fault a
    square labelled with its kind, tool and first line, at ``to_px(x, y)`` [px] of their places [mm]."""
    if report.gouged and report.gouge_position is not None:
        cx, cy = to_px(report.gouge_position[0], report.gouge_position[1])
        for r in (9, 10):
            draw.ellipse([cx - r, cy - r, cx + r, cy + r], outline=(255, 255, 255))
        draw.ellipse([cx - 11, cy - 11, cx + 11, cy + 11], outline=(0, 0, 0))
    for crash in report.rapid_crashes:
        cx, cy = to_px(crash.position[0], crash.position[1])
        draw.line([(cx - 7, cy - 7), (cx + 7, cy + 7)], fill=(255, 0, 255), width=3)
        draw.line([(cx - 7, cy + 7), (cx + 7, cy - 7)], fill=(255, 0, 255), width=3)
    # Every other fault: a black-and-white square at its worst point, labelled with its
    # kind and first program line (rapids already carry their cross).
    for fault in report.faults:
        if fault.position is None or fault.kind == "rapid":
            continue
        cx, cy = to_px(fault.position[0], fault.position[1])
        draw.rectangle([cx - 8, cy - 8, cx + 8, cy + 8], outline=(0, 0, 0), width=3)
        draw.rectangle([cx - 6, cy - 6, cx + 6, cy + 6], outline=(255, 255, 255), width=1)
        label = f"{fault.kind} T{fault.tool}" + (f" L{fault.lines[0]}" if fault.lines else "")
        draw.text((cx + 10, cy - 6), label, fill=(0, 0, 0), font=font)
