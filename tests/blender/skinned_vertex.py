"""Imports a skinned glTF/GLB into Blender (headless) and prints where given vertices are,
after the armature deforms the mesh, at given times.

Run by the bind tests:
    blender -b --factory-startup --python-exit-code 1 --python skinned_vertex.py -- FILE T X,Y,Z ...
Each X,Y,Z is a rest position in glTF coordinates; the vertex of the skinned mesh nearest to it
(at the rest pose, before any animation) is the one reported. Prints one JSON line starting with
`SKINNED ` on stdout:
    {"vertices": [{"rest_gltf": [...], "index": i, "rest_distance": d, "at": [x, y, z]}]}
with `at` in glTF coordinates (Blender's (x, y, z) is glTF's (x, z, -y)), evaluated at time T.
"""

import json
import sys

import bpy
import numpy

# Debian 12's Blender 3.4.1 glTF importer still says `numpy.bool` (see sample_gltf.py).
if not hasattr(numpy, "bool"):
    numpy.bool = bool

args = sys.argv[sys.argv.index("--") + 1 :]
path, t = args[0], float(args[1])
targets = [[float(c) for c in a.split(",")] for a in args[2:]]

bpy.ops.wm.read_factory_settings(use_empty=True)
result = bpy.ops.import_scene.gltf(filepath=path)
if "FINISHED" not in result:
    raise SystemExit(f"glTF import failed: {result}")

scene = bpy.context.scene
meshes = [o for o in scene.objects if o.type == "MESH"]
if len(meshes) != 1:
    raise SystemExit(f"expected one mesh object, found {[o.name for o in meshes]}")
obj = meshes[0]
if not any(m.type == "ARMATURE" for m in obj.modifiers):
    raise SystemExit("the mesh has no armature modifier: the skin was not imported")


def to_gltf(v):
    return [v[0], v[2], -v[1]]


def evaluated_positions():
    depsgraph = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(depsgraph)
    mesh = ev.to_mesh()
    world = ev.matrix_world
    out = [to_gltf(world @ v.co) for v in mesh.vertices]
    ev.to_mesh_clear()
    return out


# Rest pose: the armature shown at rest, whatever the action says.
for o in scene.objects:
    if o.type == "ARMATURE":
        o.data.pose_position = "REST"
bpy.context.view_layer.update()
rest = numpy.array(evaluated_positions())
for o in scene.objects:
    if o.type == "ARMATURE":
        o.data.pose_position = "POSE"

fps = scene.render.fps / scene.render.fps_base
frame = t * fps
whole = int(frame // 1)
scene.frame_set(whole, subframe=frame - whole)
bpy.context.view_layer.update()
posed = evaluated_positions()

report = []
for target in targets:
    d = numpy.linalg.norm(rest - numpy.array(target), axis=1)
    i = int(numpy.argmin(d))
    report.append({"rest_gltf": target, "index": i, "rest_distance": float(d[i]), "at": posed[i]})
print("SKINNED " + json.dumps({"fps": fps, "vertices": report}))
