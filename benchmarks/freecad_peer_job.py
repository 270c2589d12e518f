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
diameter): one Adaptive "Outside" around the part's outline down to ``floor_z``, and one
Adaptive "Inside" per level of upward flat faces below the stock top, from the stock top down
to that level. Then FreeCAD's LinuxCNC post writes the program. It prints one JSON line:
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

faces = list(enumerate(model.Shape.Faces, start=1))
bottom = min(f.BoundBox.ZMin for _, f in faces)
levels = {}
for i, f in faces:
    n = f.normalAt(0, 0)
    if n.z > 0.999 and f.BoundBox.ZLength < 1e-3 and f.BoundBox.ZMax < top - 1e-3:
        levels.setdefault(round(f.BoundBox.ZMax, 3), []).append(f"Face{i}")
outline = [f"Face{i}" for i, f in faces
           if f.normalAt(0, 0).z < -0.999 and abs(f.BoundBox.ZMin - bottom) < 1e-3]


def adaptive(name, subs, side, final_z, use_outline):
    """One Adaptive clearing at FreeCAD's defaults but the step-down, which it leaves to the job."""
    op = PathAdaptive.Create(name, parentJob=job)
    op.ToolController = tc
    op.Base = [(model, subs)]
    op.Side = side
    op.OperationType = "Clearing"
    op.UseOutline = use_outline
    op.setExpression("StepDown", None)
    op.StepDown = tool["diameter"]
    op.setExpression("StartDepth", None)
    op.StartDepth = top
    op.setExpression("FinalDepth", None)
    op.FinalDepth = final_z
    return op


ops = [adaptive("AdaptiveOutside", outline, "Outside", args["floor_z"], True)]
for k, (z, subs) in enumerate(sorted(levels.items(), reverse=True)):
    ops.append(adaptive(f"AdaptiveLevel{k}", subs, "Inside", z, False))
doc.recompute()
linuxcnc_post.export([tc] + ops, args["gcode"], "--no-show-editor")
print(json.dumps({
    "ops": [{"name": op.Name, "side": op.Side, "faces": len(op.Base[0][1]), "final_z": op.FinalDepth.Value,
             "commands": len(op.Path.Commands)} for op in ops],
    "commands": sum(len(op.Path.Commands) for op in ops),
    "seconds": round(time.perf_counter() - t0, 2),
}))
