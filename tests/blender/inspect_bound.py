"""Imports a bound GLB into Blender (headless) and prints what came through, for the bind tests.

    blender -b --factory-startup --python-exit-code 1 --python inspect_bound.py -- FILE [T X,Y,Z]

Prints one JSON line starting with `BOUND `:
    {"meshes": {name: {"vertices": n, "uv_layers": [...], "images": [[name, w, h], ...],
                       "shape_keys": [...], "armature": bool, "groups": [...]}},
     "bones": [...], "actions": [...], "moved": d}
`moved` (with T and a rest position X,Y,Z in glTF coordinates): how far the face's vertex
nearest to that position is from its rest at time T, once every action plays (glTF units).
"""

import json
import sys

import bpy
import numpy

# Debian 12's Blender 3.4.1 glTF importer still says `numpy.bool` (see sample_gltf.py).
if not hasattr(numpy, "bool"):
    numpy.bool = bool

args = sys.argv[sys.argv.index("--") + 1 :]
path = args[0]
bpy.ops.wm.read_factory_settings(use_empty=True)
result = bpy.ops.import_scene.gltf(filepath=path)
if "FINISHED" not in result:
    raise SystemExit(f"glTF import failed: {result}")
scene = bpy.context.scene

out = {"meshes": {}, "bones": [], "actions": [a.name for a in bpy.data.actions]}
for o in scene.objects:
    if o.type == "ARMATURE":
        out["bones"] += [b.name for b in o.data.bones]
    if o.type != "MESH":
        continue
    images = []
    for slot in o.material_slots:
        if slot.material and slot.material.use_nodes:
            for node in slot.material.node_tree.nodes:
                if node.type == "TEX_IMAGE" and node.image:
                    images.append([node.image.name, *node.image.size])
    keys = o.data.shape_keys.key_blocks.keys() if o.data.shape_keys else []
    out["meshes"][o.name] = {
        "vertices": len(o.data.vertices),
        "uv_layers": [uv.name for uv in o.data.uv_layers],
        "images": images,
        "shape_keys": list(keys),
        "armature": any(m.type == "ARMATURE" and m.object for m in o.modifiers),
        "groups": [g.name for g in o.vertex_groups],
    }


def to_gltf(v):
    return [v[0], v[2], -v[1]]


def positions(obj):
    depsgraph = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(depsgraph)
    mesh = ev.to_mesh()
    world = ev.matrix_world
    p = numpy.array([to_gltf(world @ v.co) for v in mesh.vertices])
    ev.to_mesh_clear()
    return p


if len(args) >= 3:
    t = float(args[1])
    target = numpy.array([float(c) for c in args[2].split(",")])
    face = max(
        (o for o in scene.objects if o.type == "MESH" and "P1" in o.vertex_groups),
        key=lambda o: len(o.data.vertices),
    )
    # every armature plays the action the importer gave it (the take's is the one named `take`)
    for o in scene.objects:
        if o.type == "ARMATURE" and o.animation_data:
            take = [a for a in bpy.data.actions if a.name.startswith("take")]
            if take:
                o.animation_data.action = take[0]
    scene.frame_set(0)
    bpy.context.view_layer.update()
    rest = positions(face)
    i = int(numpy.argmin(numpy.linalg.norm(rest - target, axis=1)))
    fps = scene.render.fps / scene.render.fps_base
    frame = t * fps
    scene.frame_set(int(frame), subframe=frame - int(frame))
    bpy.context.view_layer.update()
    out["moved"] = float(numpy.linalg.norm(positions(face)[i] - rest[i]))
    out["rest_distance"] = float(numpy.linalg.norm(rest[i] - target))
print("BOUND " + json.dumps(out))
