"""Independent check of a `mouthpiece export` glTF/GLB against the take it came from.

Reads the glTF with nothing but json, struct and numpy (no glTF library, nothing shared with
the Rust writer), evaluates every point's LINEAR translation channel at every frame time of
the take, and compares with the take's points. With a character file it also checks that the
node hierarchy puts each point's rest position where the character file puts it in the model
(in metres, glTF axes). When the take has the rig (`rig` on its lines) it checks the `jaw`
node's rotation keys (about the x axis, by the take's jaw angle) and translation keys (the
pivot moved by the slide), and the `blendshapes` node: its mesh's morph targets, named by
`extras.targetNames` as the take names its curves, and one weight per curve and frame equal
to the take's (0 and the jaw at rest on lines without `rig`).

    python check_gltf.py --take TAKE.jsonl --gltf OUT.glb [--character C.toml] [--model-up y|z]

Prints one JSON object: counts and the largest errors found (the test judges them).
"""

import argparse
import base64
import json
import math
import os
import struct
import sys
import tomllib

import numpy as np

COMPONENT = {5126: ("<f4", 4), 5123: ("<u2", 2), 5125: ("<u4", 4)}
WIDTH = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}


def load(path):
    data = open(path, "rb").read()
    if data[:4] == b"glTF":
        magic, version, length = struct.unpack_from("<4sII", data, 0)
        assert version == 2 and length == len(data), (version, length, len(data))
        json_len, json_type = struct.unpack_from("<I4s", data, 12)
        assert json_type == b"JSON"
        doc = json.loads(data[20 : 20 + json_len])
        offset = 20 + json_len
        bin_len, bin_type = struct.unpack_from("<I4s", data, offset)
        assert bin_type == b"BIN\0"
        buffers = [data[offset + 8 : offset + 8 + bin_len]]
    else:
        doc = json.loads(data)
        buffers = []
        for b in doc["buffers"]:
            uri = b["uri"]
            if uri.startswith("data:"):
                buffers.append(base64.b64decode(uri.split(",", 1)[1]))
            else:
                from urllib.parse import unquote

                buffers.append(open(os.path.join(os.path.dirname(path), unquote(uri)), "rb").read())
    for b, raw in zip(doc["buffers"], buffers):
        assert len(raw) >= b["byteLength"], "buffer shorter than declared"
    return doc, buffers


def accessor(doc, buffers, index):
    acc = doc["accessors"][index]
    view = doc["bufferViews"][acc["bufferView"]]
    dtype, size = COMPONENT[acc["componentType"]]
    width = WIDTH[acc["type"]]
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    count = acc["count"]
    raw = buffers[view["buffer"]][start : start + count * width * size]
    values = np.frombuffer(raw, dtype=dtype).reshape(count, width)
    if "min" in acc:
        assert np.array_equal(values.min(axis=0), np.array(acc["min"], dtype=dtype)), "accessor min"
        assert np.array_equal(values.max(axis=0), np.array(acc["max"], dtype=dtype)), "accessor max"
    return values.astype(np.float64)


def quat_matrix(q):
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def quat_mul(a, b):
    """Hamilton product of quaternions given as [x, y, z, w]."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ]
    )


def node_matrix(node):
    m = np.eye(4)
    s = np.diag(node.get("scale", [1, 1, 1]))
    r = quat_matrix(node.get("rotation", [0, 0, 0, 1]))
    m[:3, :3] = r @ s
    m[:3, 3] = node.get("translation", [0, 0, 0])
    return m


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--take", required=True)
    ap.add_argument("--gltf", required=True)
    ap.add_argument("--character")
    ap.add_argument("--model-up", default="y", choices=["y", "z"])
    args = ap.parse_args()

    frames = [json.loads(line) for line in open(args.take) if line.strip()]
    # Evaluate at the times glTF can hold (f32): the take's times rounded as the exporter must.
    # That separates value errors from the inherent time rounding (up to 2.4e-7 s at t = 4 s).
    times = np.array([f["t"] for f in frames]).astype(np.float32).astype(np.float64)
    doc, buffers = load(args.gltf)

    scene = doc["scenes"][doc.get("scene", 0)]
    assert len(scene["nodes"]) in (1, 2), "the mouth, and the head when the take has one"
    mouth_index = scene["nodes"][0]
    head = doc["nodes"][scene["nodes"][1]] if len(scene["nodes"]) == 2 else None
    if head is not None:
        assert head["name"] == "head", head.get("name")
        eyes = [doc["nodes"][i]["name"] for i in head["children"]]
        assert eyes == ["eye_L", "eye_R"], eyes
    mouth = doc["nodes"][mouth_index]
    assert mouth["name"] == "mouth", mouth.get("name")
    rig_node_names = ("curve", "jaw", "blendshapes", "lip_upper", "lip_lower")
    children = [doc["nodes"][i] for i in mouth["children"] if doc["nodes"][i]["name"] not in rig_node_names]
    rig_nodes = {doc["nodes"][i]["name"]: doc["nodes"][i] for i in mouth["children"] if doc["nodes"][i]["name"] in rig_node_names[1:]}
    names = [c["name"] for c in children]
    curve_groups = [doc["nodes"][i] for i in mouth["children"] if doc["nodes"][i]["name"] == "curve"]

    if args.character:
        character = tomllib.load(open(args.character, "rb"))
        expected_names = list(character["points"].keys())
    else:
        expected_names = list(frames[0]["points"].keys())
    assert names == expected_names, (names, expected_names)

    animation = doc["animations"][0]
    by_node = {}
    rotations = {}
    weights = None
    for ch in animation["channels"]:
        node_name = doc["nodes"][ch["target"]["node"]]["name"]
        sampler = animation["samplers"][ch["sampler"]]
        assert sampler.get("interpolation", "LINEAR") == "LINEAR"
        t = accessor(doc, buffers, sampler["input"])[:, 0]
        v = accessor(doc, buffers, sampler["output"])
        if ch["target"]["path"] == "weights":
            assert node_name == "blendshapes", node_name
            mesh = doc["meshes"][doc["nodes"][ch["target"]["node"]]["mesh"]]
            targets = len(mesh["primitives"][0]["targets"])
            assert v.shape[0] == len(t) * targets, (v.shape, len(t), targets)
            weights = (t, v.reshape(len(t), targets), mesh)
            continue
        if node_name in ("jaw", "lip_upper", "lip_lower"):
            rotations[node_name + " " + ch["target"]["path"]] = (t, v)
            continue
        if ch["target"]["path"] == "rotation":
            assert node_name in ("head", "eye_L", "eye_R"), node_name
            rotations[node_name] = (t, v)
            continue
        assert ch["target"]["path"] == "translation"
        by_node[node_name] = (t, v)

    max_error = 0.0
    max_time_error = 0.0
    keys = 0
    width = 0.0
    for name in names:
        t, v = by_node[name]
        keys += len(t)
        assert np.all(np.diff(t) > 0), f"{name}: key times not increasing"
        expected = np.array([f["points"][name] for f in frames])
        width = max(width, np.ptp(expected[:, 0]))
        # Every key sits at one of the take's times (as f32).
        nearest = np.abs(t[:, None] - times[None, :]).min(axis=1)
        max_time_error = max(max_time_error, float(nearest.max()))
        for k in range(3):
            got = np.interp(times, t, v[:, k])
            max_error = max(max_error, float(np.abs(got - expected[:, k]).max()))

    curve_error = None
    if curve_groups:
        curve_names = [doc["nodes"][i]["name"] for i in curve_groups[0]["children"]]
        curve_error = 0.0
        for i, name in enumerate(curve_names):
            assert name == f"C{i}", name
            t, v = by_node[name]
            keys += len(t)
            # Lines before the neutral pose (`process`) have no curve points: no keys there.
            shaped = [j for j, f in enumerate(frames) if f["curve"]["points"]]
            expected = np.array([frames[j]["curve"]["points"][i] for j in shaped])
            for k in range(3):
                got = np.interp(times[shaped], t, v[:, k])
                curve_error = max(curve_error, float(np.abs(got - expected[:, k]).max()))

    # Head and eyes: one key per frame, each the take's quaternion ([w, x, y, z] there,
    # [x, y, z, w] in glTF; the head's carries the model-axes conversion C), up to sign, and
    # consecutive keys in one hemisphere (so interpolation takes the short way).
    head_error = None
    head_keys = 0
    if head is not None:
        head_error = 0.0
        c = np.array([-np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)]) if args.model_up == "z" else None
        for name, key in (("head", "rotation"), ("eye_L", "eye_left"), ("eye_R", "eye_right")):
            t, v = rotations[name]
            head_keys += len(t)
            assert len(t) == len(frames), (name, len(t), len(frames))
            assert np.all(np.diff(t) > 0), f"{name}: key times not increasing"
            assert np.all(np.einsum("ij,ij->i", v[1:], v[:-1]) >= 0), f"{name}: hemisphere flip"
            for f, got in zip(frames, v):
                w, x, y, z = f["character_head"][key]
                want = np.array([x, y, z, w])
                if name == "head" and c is not None:
                    want = quat_mul(c, want)
                err = min(np.abs(got - want).max(), np.abs(got + want).max())
                head_error = max(head_error, float(err))

    # The rig: jaw and curves, one key per frame.
    rig_frames = [f.get("rig") for f in frames]
    rig = {"rig_frames": sum(r is not None for r in rig_frames)}
    if weights is not None or rig["rig_frames"]:
        assert rig["rig_frames"] > 0, "rig nodes for a take without rig"
        assert set(rig_nodes) == {"jaw", "blendshapes", "lip_upper", "lip_lower"}, list(rig_nodes)
        t, w, mesh = weights
        curve_names = list(next(r for r in rig_frames if r is not None)["curves"].keys())
        assert mesh["extras"]["targetNames"] == curve_names, mesh["extras"]
        assert mesh["weights"] == [0.0] * len(curve_names), mesh["weights"]
        # Each target raises its own bar of the meter (two vertices) and nothing else.
        prim = mesh["primitives"][0]
        for i, target in enumerate(prim["targets"]):
            d = accessor(doc, buffers, target["POSITION"])
            moved = np.flatnonzero(np.abs(d).sum(axis=1))
            assert list(moved) == [4 * i + 2, 4 * i + 3], (i, moved)
        assert len(t) == len(frames) and np.array_equal(t, times), "one weight key per frame"
        want = np.array([[r["curves"][n] if r else 0.0 for n in curve_names] for r in rig_frames])
        rig["rig_keys"] = int(len(t))
        rig["target_names"] = curve_names
        rig["max_weight_error"] = float(np.abs(w - want).max())
        rt, rq = rotations["jaw rotation"]
        tt, tv = rotations["jaw translation"]
        assert np.array_equal(rt, times) and np.array_equal(tt, times)
        angles = np.array([r["jaw"]["angle_deg"] if r else 0.0 for r in rig_frames])
        # A rotation about +x only, by the take's angle.
        assert np.abs(rq[:, 1:3]).max() < 1e-7, "jaw turns about x only"
        got = np.degrees(2 * np.arctan2(rq[:, 0], rq[:, 3]))
        rig["max_jaw_angle_error_deg"] = float(np.abs(got - angles).max())
        rest = np.array(rig_nodes["jaw"]["translation"])
        scale = 1.0
        if args.character:
            scale = UNITS.get(tomllib.load(open(args.character, "rb")).get("units", "m"), 1.0)
        # The slide and the lips' translations in the character's units: its mouth width (the
        # x extent of the points' rest positions, its units) over the performer's
        # (`performer_width_m`); without that, the performer's metres in the character's units.
        char_width = float(np.ptp([c["translation"][0] for c in children]))

        def per_metre(r):
            if r and r.get("performer_width_m") and char_width > 0:
                return char_width / r["performer_width_m"]
            return 1.0 / scale

        factors = np.array([per_metre(r) for r in rig_frames])
        slides = np.array([r["jaw"]["slide_m"] if r else 0.0 for r in rig_frames]) * factors
        want_t = rest[None, :] + np.stack([slides, 0 * slides, 0 * slides], axis=1)
        rig["max_jaw_slide_error"] = float(np.abs(tv - want_t).max())
        lip_error = 0.0
        for lip in ("upper", "lower"):
            lt, lv = rotations[f"lip_{lip} translation"]
            qt, qv = rotations[f"lip_{lip} rotation"]
            assert np.array_equal(lt, times) and np.array_equal(qt, times)
            want_lt = np.array([r["lips"][lip]["translation"] if r else [0.0] * 3 for r in rig_frames]) * factors[:, None]
            lip_error = max(lip_error, float(np.abs(lv - want_lt).max()))
            wxyz = np.array([r["lips"][lip]["rotation"] if r else [1.0, 0, 0, 0] for r in rig_frames])
            want_q = np.concatenate([wxyz[:, 1:], wxyz[:, :1]], axis=1)
            err = np.minimum(np.abs(qv - want_q).max(axis=1), np.abs(qv + want_q).max(axis=1))
            lip_error = max(lip_error, float(err.max()))
        rig["max_lip_error"] = lip_error
        rig["lip_scale"] = float(factors[-1])
        rig["jaw_rest"] = rest.tolist()
        rig["max_jaw_angle_deg"] = float(np.abs(angles).max())

    result = {
        **rig,
        "head_keys": head_keys,
        "max_head_error": head_error,
        "frames": len(frames),
        "curve_points": len(curve_groups[0]["children"]) if curve_groups else 0,
        "max_curve_error": curve_error,
        "points": names,
        "keys": keys,
        "max_error": max_error,
        "max_key_time_error": max_time_error,
    }

    if args.character:
        scale = UNITS.get(character.get("units", "m"), 1.0)
        model = np.array([character["points"][n] for n in names], dtype=np.float64) * scale
        if args.model_up == "z":
            model = np.stack([model[:, 0], model[:, 2], -model[:, 1]], axis=1)
        world = node_matrix(mouth)
        rest_world = np.array(
            [(world @ np.array(c["translation"] + [1.0]))[:3] for c in children]
        )
        result["max_rest_world_error"] = float(np.abs(rest_world - model).max())
        corners = model[0] - model[len(names) // 2]
        result["mouth_width_m"] = float(np.linalg.norm(corners))
    print(json.dumps(result))


if __name__ == "__main__":
    sys.exit(main())
