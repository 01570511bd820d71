"""Builds the test avatar of `export --onto`, or samples one's shape keys after import.

Run by crates/mouthpiece/tests/integration/export_onto.rs:

    blender -b --factory-startup --python-exit-code 1 --python onto_avatar.py -- \
        make OUT FORMAT NAME[=DEFAULT] ...
        A mesh object `Face` (material `Skin`) with one shape key per NAME (each raises its
        own vertex; DEFAULT, when given, is the key's value, exported as the mesh's default
        weight), and a cube `Spinner` with a shape key `Bulge` and its own animation `Spin`
        (a turn about Z), exported with Blender's glTF exporter as FORMAT (GLB,
        GLTF_SEPARATE, GLTF_EMBEDDED).

    ... -- sample FILE ANIMATION T1 T2 ...
        Imports FILE, makes ANIMATION's NLA track the active action of every object and
        shape-key block (Blender's importer activates the file's first animation and stashes
        the others as NLA tracks named after them), and prints one JSON line `SAMPLES {...}`:
        {"fps", "objects": [...], "materials": [...], "actions": {name: [fcurve data paths]},
         "tracks": {object: [NLA track names]},
         "shape_keys": {"T": {object: {key: value}}}}.
"""

import json
import sys

import bpy
import numpy

# Debian 12's Blender 3.4.1 glTF importer still says `numpy.bool`, which Debian 12's numpy
# 1.24 removed. Restore the alias it meant.
if not hasattr(numpy, "bool"):
    numpy.bool = bool

args = sys.argv[sys.argv.index("--") + 1 :]
mode = args[0]
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene


def make(out, fmt, specs):
    # A 3 x 2 grid of quads in the XZ plane (facing -Y, Blender's front).
    cols, rows = 4, 3
    verts = [(x * 0.01, 0.0, z * 0.01) for z in range(rows) for x in range(cols)]
    faces = [
        (z * cols + x, z * cols + x + 1, (z + 1) * cols + x + 1, (z + 1) * cols + x)
        for z in range(rows - 1)
        for x in range(cols - 1)
    ]
    mesh = bpy.data.meshes.new("FaceMesh")
    mesh.from_pydata(verts, [], faces)
    face = bpy.data.objects.new("Face", mesh)
    scene.collection.objects.link(face)
    skin = bpy.data.materials.new("Skin")
    skin.use_nodes = True
    skin.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.8, 0.5, 0.4, 1.0)
    mesh.materials.append(skin)
    face.shape_key_add(name="Basis")
    for k, spec in enumerate(specs):
        name, _, default = spec.partition("=")
        key = face.shape_key_add(name=name, from_mix=False)
        key.data[k % len(verts)].co.y -= 0.005
        if default:
            key.value = float(default)

    cube = [(x, y, z) for x in (-0.01, 0.01) for y in (-0.01, 0.01) for z in (-0.01, 0.01)]
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    cube_mesh = bpy.data.meshes.new("SpinnerMesh")
    cube_mesh.from_pydata(cube, [], quads)
    spinner = bpy.data.objects.new("Spinner", cube_mesh)
    spinner.location = (0.1, 0.0, 0.0)
    scene.collection.objects.link(spinner)
    spinner.shape_key_add(name="Basis")
    bulge = spinner.shape_key_add(name="Bulge", from_mix=False)
    bulge.data[0].co.x -= 0.005
    spinner.rotation_euler = (0.0, 0.0, 0.0)
    spinner.keyframe_insert("rotation_euler", frame=1)
    spinner.rotation_euler = (0.0, 0.0, 1.5)
    spinner.keyframe_insert("rotation_euler", frame=25)
    spinner.animation_data.action.name = "Spin"

    result = bpy.ops.export_scene.gltf(
        filepath=out,
        export_format=fmt,
        export_animations=True,
        export_morph=True,
        export_materials="EXPORT",
    )
    if "FINISHED" not in result:
        raise SystemExit(f"glTF export failed: {result}")


def activate(block, animation):
    data = getattr(block, "animation_data", None)
    if data is None:
        return
    for track in data.nla_tracks:
        if track.name == animation and track.strips:
            data.action = track.strips[0].action
            return
    data.action = None


def sample(path, animation, times):
    result = bpy.ops.import_scene.gltf(filepath=path)
    if "FINISHED" not in result:
        raise SystemExit(f"glTF import failed: {result}")
    tracks = {}
    for obj in scene.objects:
        blocks = [obj]
        if obj.type == "MESH" and obj.data.shape_keys is not None:
            blocks.append(obj.data.shape_keys)
        tracks[obj.name] = [
            t.name for b in blocks if b.animation_data for t in b.animation_data.nla_tracks
        ]
        for block in blocks:
            activate(block, animation)
    fps = scene.render.fps / scene.render.fps_base
    shape_keys = {}
    for t in times:
        frame = t * fps
        whole = int(frame // 1)
        scene.frame_set(whole, subframe=frame - whole)
        bpy.context.view_layer.update()
        shape_keys[repr(t)] = {
            o.name: {k.name: k.value for k in o.data.shape_keys.key_blocks}
            for o in scene.objects
            if o.type == "MESH" and o.data.shape_keys is not None
        }
    out = {
        "fps": fps,
        "objects": sorted(o.name for o in scene.objects),
        "materials": sorted(m.name for m in bpy.data.materials),
        "actions": {a.name: sorted({f.data_path for f in a.fcurves}) for a in bpy.data.actions},
        "tracks": tracks,
        "shape_keys": shape_keys,
    }
    print("SAMPLES " + json.dumps(out))


if mode == "make":
    make(args[1], args[2], args[3:])
elif mode == "sample":
    sample(args[1], args[2], [float(t) for t in args[3:]])
else:
    raise SystemExit(f"unknown mode {mode}")
