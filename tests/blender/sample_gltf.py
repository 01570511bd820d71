"""Imports a glTF/GLB into Blender (headless) and prints where its nodes are at given times.

Run by the export tests:
    blender -b --factory-startup --python-exit-code 1 --python sample_gltf.py -- FILE T1 T2 ...
Prints one JSON line starting with `SAMPLES ` on stdout:
    {"fps": …, "objects": {name: {"parent": …}}, "samples": {"T": {name: [x, y, z]}},
     "matrices": {"T": {name: 4x4 world matrix, rows}},
     "shape_keys": {"T": {name: {shape key: value}}}}  (objects whose mesh has shape keys)
positions are world coordinates in Blender's frame (+Z up; glTF's (x, y, z) is Blender's
(x, -z, y)), so the caller can check Blender's own conversion and animation evaluation.
"""

import json
import sys

import bpy
import numpy

# Debian 12's Blender 3.4.1 glTF importer still says `numpy.bool`, which Debian 12's numpy
# 1.24 removed (mesh import fails with AttributeError). Restore the alias it meant.
if not hasattr(numpy, "bool"):
    numpy.bool = bool

args = sys.argv[sys.argv.index("--") + 1 :]
path, times = args[0], [float(t) for t in args[1:]]

bpy.ops.wm.read_factory_settings(use_empty=True)
result = bpy.ops.import_scene.gltf(filepath=path)
if "FINISHED" not in result:
    raise SystemExit(f"glTF import failed: {result}")

scene = bpy.context.scene
fps = scene.render.fps / scene.render.fps_base
objects = {o.name: {"parent": o.parent.name if o.parent else None, "type": o.type} for o in scene.objects}
actions = [a.name for a in bpy.data.actions]

samples = {}
matrices = {}
shape_keys = {}
for t in times:
    frame = t * fps
    whole = int(frame // 1)
    scene.frame_set(whole, subframe=frame - whole)
    bpy.context.view_layer.update()
    samples[repr(t)] = {o.name: list(o.matrix_world.translation) for o in scene.objects}
    matrices[repr(t)] = {o.name: [list(row) for row in o.matrix_world] for o in scene.objects}
    shape_keys[repr(t)] = {
        o.name: {k.name: k.value for k in o.data.shape_keys.key_blocks}
        for o in scene.objects
        if o.type == "MESH" and o.data.shape_keys is not None
    }

print(
    "SAMPLES "
    + json.dumps(
        {
            "fps": fps,
            "objects": objects,
            "actions": actions,
            "samples": samples,
            "matrices": matrices,
            "shape_keys": shape_keys,
        }
    )
)
