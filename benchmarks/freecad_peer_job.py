"""FreeCAD 0.20's Adaptive clearing of one part, run inside ``freecadcmd`` by benchmarks/freecad_peer.py.

Not imported by factory: FreeCAD's own Python runs it. Its inputs come as one JSON document in
the environment variable ``FACTORY_PEER_JOB`` (``freecadcmd`` takes every argument for a file
to open):

    {"stl": part in work coordinates [mm], "gcode": where to write the posted program,
     "stock_min": [x, y, z], "stock_max": [x, y, z], "floor_z": lowest Z op 1 cuts to [mm],
     "tool": {"number", "diameter", "flute_length", "length"} [mm],
     "spindle_rpm", "feed", "plunge_feed" [rev/min, mm/min]}

It makes the job a machinist makes in the Path workbench with the Adaptive operation at its
defaults (20 % stepover, helix entry at 5 degrees, no lift between passes, step-down = the tool
diameter), level by level: for each flat facing up below the stock top, and for ``floor_z``, one
Adaptive "Outside" the part's section just above that level, from the level above down to it
(where no part is above the level, around a speck beside the stock: a face pass). Then
FreeCAD's LinuxCNC post writes the program. It prints one JSON line:
``{"ops": [...], "commands": n, "seconds": wall time of FreeCAD's computation}``.
"""

import json
import os
import time

import FreeCAD
import Mesh
import Part
import PathScripts.PathAdaptive as PathAdaptive
import PathScripts.PathJob as PathJob
import PathScripts.PathStock as PathStock
import PathScripts.PathToolBit as PathToolBit
import PathScripts.PathToolController as PathToolController
from PathScripts.post import linuxcnc_post

ENDMILL = "/usr/share/freecad/Mod/Path/Tools/Shape/endmill.fcstd"

args = json.loads(os.environ["FACTORY_PEER_JOB"])
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
tool = args["tool"]
bit = PathToolBit.Factory.Create(f"T{tool['number']}", ENDMILL)
bit.Diameter = tool["diameter"]
bit.CuttingEdgeHeight = tool["flute_length"]
bit.Length = tool["length"]
tc = PathToolController.Create(f"TC{tool['number']}", bit, tool["number"], assignViewProvider=False)
tc.HorizFeed = f"{args['feed']} mm/min"
tc.VertFeed = f"{args['plunge_feed']} mm/min"
tc.SpindleSpeed = float(args["spindle_rpm"])
job.Tools.Group = [tc]
model = job.Model.Group[0]
top = hi[2]

faces = model.Shape.Faces
bottom = model.Shape.BoundBox.ZMin
# Levels: every flat that faces up below the stock top, and op 1's floor.
levels = {round(f.BoundBox.ZMax, 3) for f in faces
          if f.normalAt(0, 0).z > 0.999 and f.BoundBox.ZLength < 1e-3 and f.BoundBox.ZMax < top - 1e-3}
levels = sorted(levels | {round(args["floor_z"], 3)}, reverse=True)


def adaptive(k, start_z, final_z):
    """Adaptive "Outside" the part's section just above ``final_z``, from ``start_z`` down to it.

    FreeCAD's defaults but the step-down, which it leaves to the job, and the depths, which a
    machinist sets level by level. A part machinable from above is nowhere wider than just above
    a level, so the section keeps the tool out of the part; the stock above ``start_z`` there is
    gone already.
    """
    wires = model.Shape.slice(FreeCAD.Vector(0, 0, 1), max(final_z, bottom) + 0.01)
    section = doc.addObject("Part::Feature", f"Section{k}")
    if wires:
        section.Shape = Part.makeFace(wires, "Part::FaceMakerBullseye")
    else:
        # Nothing of the part above the level: a face pass over the whole stock, which is what
        # "Outside" clears around a speck of a face beside the stock.
        section.Shape = Part.makePlane(0.1, 0.1, FreeCAD.Vector(lo[0] - 50.0, lo[1] - 50.0, final_z))
    op = PathAdaptive.Create(f"Adaptive{k}", parentJob=job)
    op.ToolController = tc
    op.Base = [(section, [f"Face{i + 1}" for i in range(len(section.Shape.Faces))])]
    op.Side = "Outside"
    op.OperationType = "Clearing"
    for name, value in (("StepDown", tool["diameter"]), ("StartDepth", start_z), ("FinalDepth", final_z)):
        op.setExpression(name, None)
        setattr(op, name, value)
    return op


ops = [adaptive(k, start, z) for k, (start, z) in enumerate(zip([top] + levels[:-1], levels))]
doc.recompute()
linuxcnc_post.export([tc] + ops, args["gcode"], "--no-show-editor")
print(json.dumps({
    "ops": [{"name": op.Name, "side": op.Side, "start_z": op.StartDepth.Value, "final_z": op.FinalDepth.Value,
             "commands": len(op.Path.Commands)} for op in ops],
    "commands": sum(len(op.Path.Commands) for op in ops),
    "seconds": round(time.perf_counter() - t0, 2),
}))
