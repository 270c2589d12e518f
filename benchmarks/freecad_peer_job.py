"""FreeCAD 0.20's program for one part (issue 32's peer), run inside ``freecadcmd`` by benchmarks/freecad_peer.py.

Not imported by factory: FreeCAD's own Python runs it. Its inputs come as one JSON document in
the environment variable ``FACTORY_PEER_JOB`` (``freecadcmd`` takes every argument for a file
to open):

    {"stl": part in work coordinates [mm], "gcode": where to write the posted program,
     "stock_min": [x, y, z], "stock_max": [x, y, z], "floor_z": lowest Z op 1 cuts to [mm],
     "tools": [{"number", "diameter", "flute_length", "length" [mm],
                "spindle_rpm", "feed", "plunge_feed" [rev/min, mm/min]}, ...],
     "rough": tool number of the Adaptive, "finish": of the face pass and the wall profiles,
     "ball": of the 3D surface or null (no surface), "allowance": stock the Adaptive leaves [mm],
     "ball_stepover": the surface's stepover [mm], "ocl": folder holding OpenCAMLib's ``ocl``
     module or null, "lift": the Adaptive's lift on links [mm] (0: FreeCAD's default, no lift),
     "ball_stepdown": the surface's layers [mm] or null (FreeCAD's default, one pass)}

It makes the program a machinist makes in the Path workbench (issue 32's peer):
1. **Adaptive clearing** at FreeCAD's defaults (20 % stepover, helix entry at 5 degrees,
   KeepToolDownRatio 3, step-down = the tool diameter) but ``lift`` and ``StockToLeave`` (our
   roughing's allowance, so that the finishing below has something even to cut), level by level:
   for each flat facing up below the stock top, and for ``floor_z``, one Adaptive "Outside" the
   part's section just above that level, from the level above down to the level plus the
   allowance (where no part is above the level, around a speck beside the stock: a face pass).
2. **A face pass** over each height of flats, inside the flats' own outline and round the raised
   areas inside them, one pass at their height, at MillFace's default 50 % stepover (zigzag at 45
   degrees), made by Pocket Shape (:func:`face_pass` says why not MillFace).
3. **Wall profiles**: the part's contour (Profile at its defaults: outside, climb, step-down = the
   tool diameter) from the stock top down to op 1's floor; not the inner walls (:func:`profile`).
4. **A 3D surface** (Surface, OpenCAMLib's drop-cutter) with the ball over the model, kept to the
   box of its freeform faces (neither flat nor vertical) grown by the ball's radius by its own
   region (the stock's outline drawn in by BoundaryAdjustment) and down to that region's lowest
   face, at ``ball_stepover`` and FreeCAD's other defaults (lines along X, 1 mm sample interval,
   one pass; ``ball_stepdown`` makes it "Multi-pass", its layers lifting over what the layers
   above cut: OptimizeStepOverTransitions).
Then FreeCAD's LinuxCNC post writes the program, and each group of operations on its own to
``gcode`` with ``.adaptive``/``.face``/``.profile``/``.surface`` before the suffix. It prints one
JSON line: ``{"ops": [...], "commands": n, "seconds": wall time of FreeCAD's computation}``.
"""

import json
import os
import sys
import time

args = json.loads(os.environ["FACTORY_PEER_JOB"])
if args.get("ocl"):
    # PathSurface imports OpenCAMLib as ``ocl``; PyPI's wheel ships that module inside ``opencamlib``.
    sys.path.insert(0, args["ocl"])

import FreeCAD  # noqa: E402
import Mesh  # noqa: E402
import Part  # noqa: E402
import PathScripts.PathAdaptive as PathAdaptive  # noqa: E402
import PathScripts.PathJob as PathJob  # noqa: E402
import PathScripts.PathPocketShape as PathPocketShape  # noqa: E402
import PathScripts.PathProfile as PathProfile  # noqa: E402
import PathScripts.PathStock as PathStock  # noqa: E402
import PathScripts.PathToolBit as PathToolBit  # noqa: E402
import PathScripts.PathToolController as PathToolController  # noqa: E402
from PathScripts.post import linuxcnc_post  # noqa: E402

SHAPES = "/usr/share/freecad/Mod/Path/Tools/Shape/"
#: A face this close to flat (|n_z|) is a flat, this close to vertical a wall; the rest is freeform.
FLAT, WALL = 0.999, 0.02

t0 = time.perf_counter()
doc = FreeCAD.newDocument("peer")
mesh = Mesh.Mesh(args["stl"])
shell = Part.Shape()
shell.makeShapeFromMesh(mesh.Topology, 0.05)
# removeSplitter merges the mesh's coplanar triangles into the faces a machinist would pick.
solid = Part.makeSolid(shell).removeSplitter()
body = doc.addObject("Part::Feature", "part")
body.Shape = solid
doc.recompute()

job = PathJob.Create("Job", [body], None)
lo, hi = args["stock_min"], args["stock_max"]
doc.removeObject(job.Stock.Name)
job.Stock = PathStock.CreateBox(
    job, FreeCAD.Vector(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]),
    FreeCAD.Placement(FreeCAD.Vector(*lo), FreeCAD.Rotation()))
tools = {t["number"]: t for t in args["tools"]}


def controller(number):
    """FreeCAD's tool controller for one of our tools, with its spindle speed and feeds."""
    tool = tools[number]
    ball = number == args.get("ball")
    bit = PathToolBit.Factory.Create(f"T{number}", SHAPES + ("ballend.fcstd" if ball else "endmill.fcstd"))
    bit.Diameter = tool["diameter"]
    bit.CuttingEdgeHeight = tool["flute_length"]
    bit.Length = tool["length"]
    tc = PathToolController.Create(f"TC{number}", bit, number, assignViewProvider=False)
    tc.HorizFeed = f"{tool['feed']} mm/min"
    tc.VertFeed = f"{tool['plunge_feed']} mm/min"
    tc.SpindleSpeed = float(tool["spindle_rpm"])
    return tc


controllers = {n: controller(n) for n in {args["rough"], args["finish"], args.get("ball")} - {None}}


def created(module, name, number):
    """An operation of ``module`` (PathAdaptive, ...) with tool ``number``'s controller. Headless, FreeCAD can
    only default an operation's controller when the job holds one (it would ask the user which), so the job
    holds just that one while the operation is made; all of them are put back before the recompute."""
    job.Tools.Group = [controllers[number]]
    op = module.Create(name, parentJob=job)
    op.ToolController = controllers[number]
    return op

model = job.Model.Group[0]
top = hi[2]
allowance = float(args["allowance"])

faces = model.Shape.Faces
bottom = model.Shape.BoundBox.ZMin
flats = [f for f in faces if f.normalAt(0, 0).z > FLAT and f.BoundBox.ZLength < 1e-3 and f.BoundBox.ZMax < top - 1e-3]
# Levels: every flat that faces up below the stock top, and op 1's floor.
levels = sorted({round(f.BoundBox.ZMax, 3) for f in flats} | {round(args["floor_z"], 3)}, reverse=True)
bands = list(zip([top] + levels[:-1], levels))


def set_depths(op, **depths):
    """Set depths FreeCAD otherwise computes by expression (StartDepth, FinalDepth, StepDown) [mm]."""
    for name, value in depths.items():
        op.setExpression(name, None)
        setattr(op, name, value)


def section(k, z):
    """The part's section just above ``z``: the face an Adaptive clears outside of.

    A part machinable from above is nowhere wider than just above a level, so the section keeps
    the tool out of the part down to the level.
    """
    wires = model.Shape.slice(FreeCAD.Vector(0, 0, 1), max(z, bottom) + 0.01)
    obj = doc.addObject("Part::Feature", f"Section{k}")
    if wires:
        obj.Shape = Part.makeFace(wires, "Part::FaceMakerBullseye")
    else:
        # Nothing of the part above the level: a speck beside the stock, which "Outside" clears
        # around (a face pass over the whole stock).
        obj.Shape = Part.makePlane(0.1, 0.1, FreeCAD.Vector(lo[0] - 50.0, lo[1] - 50.0, z))
    return obj


def adaptive(k, start_z, final_z, cut):
    """Adaptive "Outside" ``cut`` (a section) from ``start_z`` down to ``final_z`` + the allowance."""
    op = created(PathAdaptive, f"Adaptive{k}", args["rough"])
    op.Base = [(cut, [f"Face{i + 1}" for i in range(len(cut.Shape.Faces))])]
    op.Side = "Outside"
    op.OperationType = "Clearing"
    op.StockToLeave = allowance
    op.LiftDistance = float(args.get("lift") or 0.0)
    set_depths(op, StepDown=tools[args["rough"]]["diameter"], StartDepth=start_z,
               FinalDepth=min(final_z + allowance, start_z))
    return op


def profile(outline):
    """The part's contour from the stock top down to op 1's floor: Profile of ``outline``'s perimeter, the section
    just above the floor (for a part machinable from above, its silhouette).

    Not Profile with no base geometry, which is the same contour (outside the model's silhouette): FreeCAD then
    projects every face of the model onto the plane (PathUtils.getEnvelope, Path.Area.makeSections with
    project=True), and on the dome's 10,958 triangles that ran past 12 minutes (py-spy: every sample there)
    before its 3D surface began.

    Profiles of each level's section, the walls between the flats too, cut into the part on stepped_wall
    (FreeCAD 0.20 offsets one of its two loops inward, 16 mm into the upper step), so only the outer walls are
    profiled: the inner ones keep the Adaptive's allowance, which makes FreeCAD's program shorter than a
    finished part's, not longer.
    """
    op = created(PathProfile, "Profile", args["finish"])
    op.Base = [(outline, [f"Face{i + 1}" for i in range(len(outline.Shape.Faces))])]
    op.processPerimeter, op.processHoles, op.processCircles = True, False, False
    set_depths(op, StartDepth=top, FinalDepth=levels[-1])
    return op


def face_pass(k, z, group):
    """A face pass over the flats ``group`` at height ``z``, inside their own outline and round the raised areas
    inside them, one pass at MillFace's default 50 % stepover.

    Made with Pocket Shape on the flats: MillFace's "Face Region" faces over the bosses inside a flat (a
    20 mm gouge on stepped_wall) unless ExcludeRaisedAreas is set, and with it set FreeCAD 0.20 makes no path
    on these solids ("shape is not planar"). A pocket of a flat keeps its raised areas as islands.
    """
    op = created(PathPocketShape, f"Face{k}", args["finish"])
    op.Base = [(model, [f"Face{faces.index(f) + 1}" for f in group])]
    op.StepOver = 50
    set_depths(op, StartDepth=z, FinalDepth=z)
    return op


def surface():
    """3D surface with the ball over the freeform faces' box (drop-cutter lines, FreeCAD's defaults but the stepover,
    the region and the final depth). Returns the operation and the number of freeform faces.

    A machinist picks the dome's face; the part here comes from a mesh, whose dome is some 9,000 triangles,
    and FreeCAD fuses selected faces first (it ran past 15 minutes), and with "BaseBoundBox" it projects every
    face of the model (PathSurfaceSupport._preProcessEntireBase, PathUtils.getEnvelope), which ran for minutes
    before a line was dropped. So the surface scans the stock's outline ("Stock"), drawn in by its own
    BoundaryAdjustment to the freeform faces' box grown by the ball's radius (the smallest of the four margins:
    on the dome, centred in its stock, exactly that box; elsewhere a larger region, which lengthens FreeCAD's
    program, not ours). Not FreeCAD's Boundary dressup on the whole stock's lines, which does two solid booleans
    per move (on the safe program's 182,350 moves still at work after 7 minutes; last session the whole job did
    not finish in 50) and turns the rapids that cross its box into feeds (4.6 of the full surface's 13.3 min).
    The final depth is the lowest of the region's faces that are not walls, the one FreeCAD sets from the faces
    a machinist picks (on dome_mould -16 mm, not the part's bottom, so "Multi-pass" makes no layers below it).
    """
    import PathScripts.PathSurface as PathSurface  # needs ``ocl``: imported only when there is a ball

    freeform = [f for f in faces if WALL < abs(f.normalAt(0, 0).z) < FLAT]
    radius = tools[args["ball"]]["diameter"] / 2
    box = Part.makeCompound(freeform).BoundBox
    box.enlarge(radius)
    inset = max(0.0, min(box.XMin - lo[0], hi[0] - box.XMax, box.YMin - lo[1], hi[1] - box.YMax))
    region = [f for f in faces if abs(f.normalAt(0, 0).z) > WALL and box.isInside(f.BoundBox)]
    op = created(PathSurface, "Surface", args["ball"])
    op.StepOver = 100.0 * float(args["ball_stepover"]) / tools[args["ball"]]["diameter"]
    op.BoundBox = "Stock"
    # With BoundaryEnforcement (FreeCAD's default) the ball's centre keeps the radius and the tessellation's
    # tolerance (PathSurfaceSupport._calculateOffsetValue) inside the outline moved out by BoundaryAdjustment.
    op.BoundaryEnforcement = True
    tolerance = max(job.GeometryTolerance.Value / 10.0, op.LinearDeflection.Value)
    op.BoundaryAdjustment = radius + tolerance - inset
    set_depths(op, FinalDepth=min(f.BoundBox.ZMin for f in region))
    if args.get("ball_stepdown"):
        op.LayerMode = "Multi-pass"
        set_depths(op, StepDown=float(args["ball_stepdown"]))
        # Each layer lifts over what the layers above cut ("hold points") instead of feeding along the surface
        # again: without it every layer re-cut the whole top at feed (dome_mould: 131 min of surface, not 75).
        # It also leaves more in the corner pockets (verify: 10.3 mm, not 5.4): FreeCAD's program the shorter.
        op.OptimizeStepOverTransitions = True
    return op, len(freeform)


cuts = [section(k, z) for k, (_, z) in enumerate(bands)]
groups = {
    "adaptive": [adaptive(k, start, z, cut) for k, ((start, z), cut) in enumerate(zip(bands, cuts))],
    "face": [face_pass(k, z, [f for f in flats if abs(f.BoundBox.ZMax - z) < 1e-3])
             for k, z in enumerate(levels) if any(abs(f.BoundBox.ZMax - z) < 1e-3 for f in flats)],
    "profile": [profile(cuts[-1])],
}
freeform = 0
if args.get("ball") is not None:
    op, freeform = surface()
    groups["surface"] = [op]
job.Tools.Group = list(controllers.values())
doc.recompute()
ops = [op for group in groups.values() for op in group]


def posted(path, selected):
    """Post ``selected`` operations with their tool controllers, in order, to ``path``."""
    items, current = [], None
    for op in selected:
        if op.ToolController is not current:
            current = op.ToolController
            items.append(current)
        items.append(op)
    linuxcnc_post.export(items, path, "--no-show-editor")


gcode = args["gcode"]
posted(gcode, ops)
stem, suffix = os.path.splitext(gcode)
for name, group in groups.items():
    posted(f"{stem}.{name}{suffix}", group)
print(json.dumps({
    "ops": [{"name": op.Name, "group": name, "start_z": op.StartDepth.Value, "final_z": op.FinalDepth.Value,
             "commands": len(op.Path.Commands)} for name, group in groups.items() for op in group],
    "freeform_faces": freeform,
    "commands": sum(len(op.Path.Commands) for op in ops),
    "seconds": round(time.perf_counter() - t0, 2),
}))
