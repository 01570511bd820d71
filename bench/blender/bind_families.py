"""Meshes for the bind family evaluation (bench/bind_families.py), made in Blender headless.

    blender -b --factory-startup --python-exit-code 1 --python bind_families.py -- DIR

Reads DIR/baseN.obj (held-out generator heads written by `family_eval bases`, mouth frame,
mouth widths) and writes, each as NAME.obj (triangles) with NAME.json (family, mouth points,
jaw hinge):

- (a) each base decimated by quadric edge collapse to about 1 200 and 2 400 vertices;
- (d) heads modelled here, not by the generator: UV spheres and a metaball head with a
  sculpted mouth (lips raised over an ellipse, a slit groove or an open mouth cut in), each
  with its own proportions and mouth width relative to the head. The mouth points are on
  the sculpted lip line (ray cast onto the surface), corners at x = ±0.5, and the mesh is
  moved so the mouth frame's origin lies between the corners.
"""

import json
import math
import os
import re
import sys

import bmesh
import bpy
from mathutils import Vector

out_dir = sys.argv[sys.argv.index("--") + 1]


def read_obj(path):
    verts, faces = [], []
    with open(path) as f:
        for line in f:
            w = line.split()
            if not w:
                continue
            if w[0] == "v":
                verts.append(tuple(float(c) for c in w[1:4]))
            elif w[0] == "f":
                faces.append(tuple(int(i.split("/")[0]) - 1 for i in w[1:]))
    return verts, faces


def write(obj, name, family, points, hinge):
    bm = bmesh.new()
    bm.from_mesh(obj.data)
    bmesh.ops.triangulate(bm, faces=bm.faces[:])
    bm.verts.index_update()
    with open(os.path.join(out_dir, name + ".obj"), "w") as f:
        for v in bm.verts:
            f.write("v %.9g %.9g %.9g\n" % tuple(v.co))
        for face in bm.faces:
            f.write("f %s\n" % " ".join(str(v.index + 1) for v in face.verts))
    with open(os.path.join(out_dir, name + ".json"), "w") as f:
        json.dump({"family": family, "points": points, "hinge": hinge}, f)
    print("wrote", name, len(bm.verts), "vertices")
    bm.free()


def new_object(name, verts, faces):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def apply_modifier(obj, mod):
    bpy.ops.object.select_all(action="DESELECT")
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.modifier_apply(modifier=mod.name)


bpy.ops.wm.read_factory_settings(use_empty=True)

# --- (a) decimated generator heads
for name in sorted(os.listdir(out_dir)):
    if not re.fullmatch(r"base[0-9]+\.obj", name):
        continue
    stem = name[:-4]
    meta = json.load(open(os.path.join(out_dir, stem + ".json")))
    verts, faces = read_obj(os.path.join(out_dir, name))
    for target in (1200, 2400):
        obj = new_object(stem, verts, faces)
        mod = obj.modifiers.new("decimate", "DECIMATE")
        mod.decimate_type = "COLLAPSE"
        mod.ratio = target / len(verts)
        apply_modifier(obj, mod)
        write(obj, "%s_dec%d" % (stem, target), "(a) decimated", meta["points"], meta["hinge"])
        bpy.data.objects.remove(obj)


# --- (d) heads modelled here
def sculpt_mouth(obj, centre_y, upper, lower, protrusion, slit, open_mouth):
    """Lips raised over the ellipse (half-width 0.5, heights upper/lower) on the front of
    the head around (0, centre_y), a slit groove along the lips' meeting line, optionally
    cut open; returns the mouth points on the surface and the front's z at the mouth."""
    bm = bmesh.new()
    bm.from_mesh(obj.data)
    for v in bm.verts:
        x, y, z = v.co
        if z <= 0:
            continue
        dy = y - centre_y
        h = upper if dy > 0 else lower
        rho = math.hypot(x / 0.5, dy / h)
        bump = max(0.0, 1.0 - rho * rho) ** 0.6
        fade = math.exp(-max(0.0, rho - 1.0) ** 2 / 0.08)
        groove = math.exp(-(dy / 0.04) ** 2) * max(0.0, 1.0 - (x / 0.5) ** 2)
        v.co.z += protrusion * (0.7 * bump + 0.3 * fade) - slit * groove
    if open_mouth:
        doomed = [
            f
            for f in bm.faces
            if f.calc_center_median().z > 0
            and abs(f.calc_center_median().y - centre_y) < 0.045
            and abs(f.calc_center_median().x) < 0.4
        ]
        print("cut", len(doomed), "faces")
        bmesh.ops.delete(bm, geom=doomed, context="FACES")
    bm.to_mesh(obj.data)
    obj.data.update()
    bm.free()
    bpy.context.view_layer.update()
    points = []
    for k in range(12):
        a = k * math.pi / 6
        s = math.sin(a)
        h = upper if s >= 0 else lower
        x, y = 0.5 * math.cos(a), centre_y + h * math.copysign(abs(s) ** 0.8, s)
        hit, loc, _, _ = obj.ray_cast(Vector((x, y, 50.0)), Vector((0, 0, -1)))
        assert hit, "no surface under mouth point %d" % k
        points.append(list(loc))
    return points


def finish(obj, name, points, hinge_back):
    # mouth frame: origin between the corners (P1, P7); the corners share y and z
    origin = [0.5 * (points[0][c] + points[6][c]) for c in range(3)]
    for v in obj.data.vertices:
        v.co -= Vector(origin)
    obj.data.update()
    points = [[p[c] - origin[c] for c in range(3)] for p in points]
    write(obj, name, "(d) modelled in Blender", points, [0.0, 0.0, -hinge_back])


def uv_head(name, radius, scale, segments, rings):
    bpy.ops.mesh.primitive_uv_sphere_add(segments=segments, ring_count=rings, radius=radius)
    obj = bpy.context.active_object
    obj.name = name
    obj.scale = scale
    bpy.ops.object.transform_apply(location=True, rotation=True, scale=True)
    return obj


# each head twice: the mouth cut open (a slit through the surface) and closed (a groove,
# the lips one surface): the feature the default's rule reads (docs/bind.md)
for open_mouth in (True, False):
    suffix = "open" if open_mouth else "closed"
    # a round head, wide mouth (0.38 of the head's width)
    obj = uv_head("sphere_wide", 1.3, (1.0, 1.25, 0.9), 160, 120)
    pts = sculpt_mouth(obj, -0.45, 0.16, 0.2, 0.12, 0.05, open_mouth)
    finish(obj, "sphere_wide_" + suffix, pts, 1.0)
    bpy.data.objects.remove(obj)
    # a long narrow head, narrow mouth (0.25 of the head's width), deep face
    obj = uv_head("sphere_narrow", 2.0, (1.0, 1.3, 1.4), 192, 128)
    pts = sculpt_mouth(obj, -0.9, 0.12, 0.15, 0.08, 0.06, open_mouth)
    finish(obj, "sphere_narrow_" + suffix, pts, 1.2)
    bpy.data.objects.remove(obj)

# a metaball head: cranium and a muzzle, the mouth on the muzzle's front
for open_mouth in (True, False):
    mb = bpy.data.metaballs.new("meta")
    mb.resolution = 0.07
    mb.render_resolution = 0.07
    e = mb.elements.new()
    e.co = (0.0, 0.9, -1.6)
    e.radius = 2.0
    e = mb.elements.new(type="ELLIPSOID")
    e.co = (0.0, -0.1, -0.3)
    e.radius = 1.4
    e.size_x, e.size_y, e.size_z = 1.0, 0.7, 1.2
    mobj = bpy.data.objects.new("meta", mb)
    bpy.context.scene.collection.objects.link(mobj)
    bpy.ops.object.select_all(action="DESELECT")
    mobj.select_set(True)
    bpy.context.view_layer.objects.active = mobj
    bpy.ops.object.convert(target="MESH")
    obj = bpy.context.active_object
    obj.name = "metaball_muzzle"
    # the muzzle's front as z = 0 side up: move the front to positive z
    front = max(v.co.z for v in obj.data.vertices)
    for v in obj.data.vertices:
        v.co.z -= front - 0.5
    obj.data.update()
    pts = sculpt_mouth(obj, -0.15, 0.14, 0.18, 0.1, 0.05, open_mouth)
    finish(obj, "metaball_" + ("open" if open_mouth else "closed"), pts, 1.4)
    bpy.data.objects.remove(obj)
    try:
        bpy.data.objects.remove(mobj)
    except ReferenceError:  # the conversion may have removed it already
        pass
