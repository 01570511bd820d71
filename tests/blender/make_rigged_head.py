"""Models a rigger's head in Blender (headless) and exports it as GLB, for the bind tests.

    blender -b --factory-startup --python-exit-code 1 --python make_rigged_head.py -- OUT.glb OUT.toml

The head is nothing like mouthpiece's procedural ones: a UV sphere (its own topology and
proportions) with a generated image texture on its UVs, a shape key, skinned to an armature
(`root` → `neck` → `head`, the lower rings weighted to the neck) that has an action; two eyes
parented to the `head` bone; teeth and a tongue as separate unparented objects. Twelve empties
`P1` … `P12` mark the mouth on the sphere's front, and the character file written next to it
holds the same points (glTF's axes, metres), so the character matches the mesh.
"""

import math
import sys

import bpy
from mathutils import Vector

args = sys.argv[sys.argv.index("--") + 1 :]
out_glb, out_toml = args[0], args[1]

bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene

CENTRE = Vector((0.0, 0.03, 0.02))
RADIUS = 0.1

# --- the head: a UV sphere with UVs, a textured material and a shape key
bpy.ops.mesh.primitive_uv_sphere_add(segments=48, ring_count=32, radius=RADIUS, location=CENTRE)
head = bpy.context.active_object
head.name = "Head"
head.data.name = "HeadMesh"
bpy.ops.object.transform_apply(location=True, rotation=True, scale=True)
bpy.ops.object.shade_smooth()

image = bpy.data.images.new("skin", width=32, height=32)
pixels = []
for y in range(32):
    for x in range(32):
        pixels += [x / 31.0, y / 31.0, 0.5, 1.0]
image.pixels = pixels
image.file_format = "PNG"
image.pack()
material = bpy.data.materials.new("SkinMaterial")
material.use_nodes = True
bsdf = material.node_tree.nodes["Principled BSDF"]
tex = material.node_tree.nodes.new("ShaderNodeTexImage")
tex.image = image
material.node_tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
head.data.materials.append(material)

head.shape_key_add(name="Basis")
puff = head.shape_key_add(name="Puff")
for i, v in enumerate(head.data.vertices):
    puff.data[i].co = v.co + (v.co - CENTRE) * 0.05

# --- the mouth: 12 points around the front of the sphere (Blender's front is -y)
# glTF (x, y, z) = Blender (x, z, -y): the mouth frame's z (out of the mouth) is Blender's -y.
MOUTH = CENTRE + Vector((0.0, -RADIUS, 0.0)).normalized() * RADIUS + Vector((0, 0, -0.03))
lip = [
    (0.025, 0.0, 0.0),
    (0.0217, 0.0055, 0.004),
    (0.0125, 0.0090, 0.008),
    (0.0, 0.0080, 0.010),
    (-0.0125, 0.0090, 0.008),
    (-0.0217, 0.0055, 0.004),
    (-0.025, 0.0, 0.0),
    (-0.0217, -0.0060, 0.003),
    (-0.0125, -0.0100, 0.007),
    (0.0, -0.0110, 0.009),
    (0.0125, -0.0100, 0.007),
    (0.0217, -0.0060, 0.003),
]
points = []
for k, (x, y, z) in enumerate(lip):
    p = MOUTH + Vector((x, 0.0, y))
    p = CENTRE + (p - CENTRE).normalized() * RADIUS  # on the sphere
    points.append(p)
    empty = bpy.data.objects.new(f"P{k + 1}", None)
    empty.location = p
    empty.empty_display_size = 0.003
    scene.collection.objects.link(empty)

# --- the armature: root → neck → head, with an action on the head
arm_data = bpy.data.armatures.new("Rig")
rig = bpy.data.objects.new("Rig", arm_data)
scene.collection.objects.link(rig)
bpy.context.view_layer.objects.active = rig
bpy.ops.object.mode_set(mode="EDIT")
bones = {}
for name, head_at, tail_at, parent in [
    ("root", (0, 0.03, -0.3), (0, 0.03, -0.2), None),
    ("neck", (0, 0.03, -0.2), (0, 0.03, -0.06), "root"),
    ("head", (0, 0.03, -0.06), (0, 0.03, 0.15), "neck"),
]:
    b = arm_data.edit_bones.new(name)
    b.head, b.tail = Vector(head_at), Vector(tail_at)
    if parent:
        b.parent = bones[parent]
        b.use_connect = True
    bones[name] = b
bpy.ops.object.mode_set(mode="OBJECT")

head_group = head.vertex_groups.new(name="head")
neck_group = head.vertex_groups.new(name="neck")
for v in head.data.vertices:
    # the lowest part of the sphere blends into the neck
    t = min(max((v.co.z - (CENTRE.z - RADIUS)) / (0.6 * RADIUS), 0.0), 1.0)
    if t > 0.0:
        head_group.add([v.index], t, "REPLACE")
    if t < 1.0:
        neck_group.add([v.index], 1.0 - t, "REPLACE")
head.parent = rig
modifier = head.modifiers.new("Armature", "ARMATURE")
modifier.object = rig

rig.animation_data_create()
action = bpy.data.actions.new("Nod")
rig.animation_data.action = action
pose_head = rig.pose.bones["head"]
pose_head.rotation_mode = "XYZ"
for frame, angle in [(1, 0.0), (12, 0.2), (24, 0.0)]:
    pose_head.rotation_euler = (angle, 0.0, 0.0)
    pose_head.keyframe_insert("rotation_euler", frame=frame)


# --- eyes on the head bone; teeth and tongue on their own
def sphere(name, location, radius):
    bpy.ops.mesh.primitive_uv_sphere_add(segments=12, ring_count=8, radius=radius, location=location)
    o = bpy.context.active_object
    o.name = name
    return o


for side, x in [("L", 0.032), ("R", -0.032)]:
    eye = sphere(f"Eye{side}", (x, -0.055, 0.05), 0.012)
    world = eye.matrix_world.copy()
    eye.parent = rig
    eye.parent_type = "BONE"
    eye.parent_bone = "head"
    eye.matrix_world = world

bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.0, -0.045, -0.005))
teeth = bpy.context.active_object
teeth.name = "TeethUpper"
teeth.scale = (0.035, 0.01, 0.006)
bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.0, -0.04, -0.03))
tongue = bpy.context.active_object
tongue.name = "Tongue"
tongue.scale = (0.025, 0.03, 0.006)

result = bpy.ops.export_scene.gltf(
    filepath=out_glb,
    export_format="GLB",
    export_skins=True,
    export_morph=True,
    export_animations=True,
    export_extras=False,
)
if "FINISHED" not in result:
    raise SystemExit(f"glTF export failed: {result}")

with open(out_toml, "w") as f:
    f.write('name = "blender-head"\nunits = "m"\n\n[points]\n')
    for k, p in enumerate(points):
        f.write(f"P{k + 1} = [{p.x!r}, {p.z!r}, {-p.y!r}]\n")
print("MADE", out_glb, out_toml)
