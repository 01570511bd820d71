"""A VMC protocol receiver built on python-osc, independent of the daemon's Rust encoder.

Receives OSC on 127.0.0.1 (an ephemeral port, written to --port-file) until --stop-file
exists, then checks what arrived and compares it with the WebSocket frames the test saved
(--stream, one JSON object per line: {"t", "rig", "head"} of the character sent over OSC):

- every frame is a run of messages ending in /VMC/Ext/Blend/Apply (in one or more bundles),
  and holds /VMC/Ext/T, /mouthpiece/Source (camera, speech or blend), the Head bone (and LeftEye/RightEye with --eyes) and one
  /VMC/Ext/Blend/Val for each of the 27 curve names (ARKit's, or in PascalCase with --names
  arkit-pascal) and of the five visemes (VRM 0.x's A I U E O with --visemes vrm0, VRM 1.0's
  aa ih ou ee oh with vrm1, none with none) before its Apply;
- every curve value is finite and within 0..1; every bone quaternion is a unit quaternion;
- a frame whose time matches a WebSocket frame's `t` carries the same curve and viseme values (float32,
  exactly as the stream's) and the same head and eye rotations after the documented axis
  conversion (the character's head-frame axes --axes, then Unity's mirrored x), computed here
  with scipy.

Prints a JSON summary on stdout; exits 1 with the reasons on stderr when a check fails.
"""

import argparse
import json
import math
import os
import pathlib
import struct
import sys

import numpy as np
from pythonosc.dispatcher import Dispatcher
from pythonosc.osc_server import BlockingOSCUDPServer
from scipy.spatial.transform import Rotation

CURVES = [
    "jawOpen", "mouthClose", "mouthFunnel", "mouthPucker", "mouthLeft", "mouthRight",
    "mouthSmileLeft", "mouthSmileRight", "mouthStretchLeft", "mouthStretchRight",
    "mouthRollUpper", "mouthRollLower", "mouthUpperUpLeft", "mouthUpperUpRight",
    "mouthLowerDownLeft", "mouthLowerDownRight", "mouthPressLeft", "mouthPressRight",
    "jawForward", "jawLeft", "jawRight", "mouthFrownLeft", "mouthFrownRight",
    "mouthShrugUpper", "mouthShrugLower", "mouthDimpleLeft", "mouthDimpleRight",
]
VISEMES = ["aa", "ih", "ou", "ee", "oh"]
VISEMES_VRM0 = ["A", "I", "U", "E", "O"]


def sent_names(names, visemes):
    """(sent name, "curves" or "visemes", the stream's name) for every value a frame sends."""
    out = [(c[0].upper() + c[1:] if names == "arkit-pascal" else c, "curves", c) for c in CURVES]
    if visemes != "none":
        sent = VISEMES_VRM0 if visemes == "vrm0" else VISEMES
        out += [(n, "visemes", v) for n, v in zip(sent, VISEMES)]
    return out


def f32(x):
    return struct.unpack(">f", struct.pack(">f", x))[0]


def receive(port_file, stop_file):
    messages = []
    dispatcher = Dispatcher()
    dispatcher.set_default_handler(lambda address, *args: messages.append((address, args)))
    server = BlockingOSCUDPServer(("127.0.0.1", 0), dispatcher)
    server.timeout = 0.05
    tmp = port_file + ".tmp"
    with open(tmp, "w") as f:
        f.write(str(server.server_address[1]))
    os.replace(tmp, port_file)
    while not os.path.exists(stop_file):
        server.handle_request()
    server.server_close()
    return messages


def frames_of(messages, bones, expected, problems):
    """Groups the messages into frames (each ending with Blend/Apply) and checks each."""
    frames, current = [], []
    for address, args in messages:
        current.append((address, args))
        if address != "/VMC/Ext/Blend/Apply":
            continue
        frame = {"t": None, "curves": {}, "bones": {}}
        for a, v in current[:-1]:
            if a == "/VMC/Ext/T":
                frame["t"] = v[0]
            elif a == "/VMC/Ext/Blend/Val":
                name, value = v
                if name in frame["curves"]:
                    problems.append(f"{name} twice before one Apply")
                frame["curves"][name] = value
            elif a == "/VMC/Ext/Bone/Pos":
                frame["bones"][v[0]] = v[1:]
            elif a == "/mouthpiece/Source":
                if len(v) != 1 or v[0] not in ("camera", "speech", "blend"):
                    problems.append(f"/mouthpiece/Source {v}: expected camera, speech or blend")
                frame["source"] = v[0] if v else None
            elif a != "/VMC/Ext/OK":
                problems.append(f"unexpected address {a}")
        if sorted(frame["curves"]) != sorted(expected):
            problems.append(f"Apply after curves {sorted(frame['curves'])}")
        if frame["t"] is None:
            problems.append("a frame without /VMC/Ext/T")
        if "source" not in frame:
            problems.append("a frame without /mouthpiece/Source")
        if sorted(frame["bones"]) != sorted(bones):
            problems.append(f"bones {sorted(frame['bones'])}, expected {sorted(bones)}")
        for name, value in frame["curves"].items():
            if not (math.isfinite(value) and 0.0 <= value <= 1.0):
                problems.append(f"{name} = {value} outside 0..1")
        for name, pose in frame["bones"].items():
            if len(pose) != 7:
                problems.append(f"{name}: {len(pose)} numbers, expected 7")
                continue
            norm = math.sqrt(sum(c * c for c in pose[3:]))
            if abs(norm - 1.0) > 1e-5:
                problems.append(f"{name} quaternion norm {norm}")
        frames.append(frame)
        current = []
    return frames


def unity_matrix(wxyz, axes):
    """The documented conversion: model-frame rotation -> head frame -> Unity axes."""
    w, x, y, z = wxyz
    r = Rotation.from_quat([x, y, z, w]).as_matrix()
    a = np.asarray(axes, dtype=float)
    s = np.diag([-1.0, 1.0, 1.0])
    return s @ a.T @ r @ a @ s


def compare(frames, stream, axes, bones, expected, problems):
    by_t = sorted(stream, key=lambda s: s["t"])
    ts = np.array([s["t"] for s in by_t])
    matched = with_rig = 0
    for frame in frames:
        if frame["t"] is None or len(ts) == 0:
            continue
        i = int(np.argmin(np.abs(ts - frame["t"])))
        if abs(ts[i] - frame["t"]) > 1e-3:
            continue
        s = by_t[i]
        matched += 1
        rig = s.get("rig")
        if rig is not None:
            with_rig += 1
        for name, group, key in expected:
            want = f32(rig[group][key]) if rig is not None else 0.0
            got = frame["curves"].get(name)
            if got is None or abs(got - want) > 1e-6:
                problems.append(f"t={frame['t']}: {name} {got} over OSC, {want} on the WebSocket")
        head = s.get("head") or {}
        for bone, key in [("Head", "rotation"), ("LeftEye", "eye_left"), ("RightEye", "eye_right")]:
            if bone not in bones:
                continue
            want = unity_matrix(head.get(key, [1.0, 0.0, 0.0, 0.0]), axes)
            pose = frame["bones"].get(bone)
            if pose is None:
                continue
            got = Rotation.from_quat(pose[3:]).as_matrix()
            err = float(np.max(np.abs(got - want)))
            if err > 1e-5:
                problems.append(f"t={frame['t']}: {bone} rotation off by {err}")
            if any(abs(p) > 0.0 for p in pose[:3]):
                problems.append(f"{bone} position {pose[:3]}, expected 0")
    return matched, with_rig


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--port-file", required=True)
    parser.add_argument("--stop-file", required=True)
    parser.add_argument("--stream", required=True, help="WebSocket frames (JSONL) to compare with")
    parser.add_argument("--axes", required=True, help="3x3 JSON: head-frame axes as columns")
    parser.add_argument("--eyes", action="store_true")
    parser.add_argument("--min-matched", type=int, default=30)
    parser.add_argument("--names", choices=["arkit", "arkit-pascal"], default="arkit")
    parser.add_argument("--visemes", choices=["vrm0", "vrm1", "none"], default="vrm0")
    args = parser.parse_args()

    messages = receive(args.port_file, args.stop_file)
    bones = ["Head"] + (["LeftEye", "RightEye"] if args.eyes else [])
    problems = []
    expected = sent_names(args.names, args.visemes)
    frames = frames_of(messages, bones, [n for n, _, _ in expected], problems)
    stream = [json.loads(line) for line in pathlib.Path(args.stream).read_text().splitlines() if line]
    matched, with_rig = compare(frames, stream, json.loads(args.axes), bones, expected, problems)
    if matched < args.min_matched:
        problems.append(f"only {matched} OSC frames matched a WebSocket frame (want {args.min_matched})")
    if with_rig == 0:
        problems.append("no matched frame carried a rig")
    jaw = [f["curves"].get(expected[0][0], 0.0) for f in frames]
    print(json.dumps({
        "messages": len(messages),
        "frames": len(frames),
        "matched": matched,
        "matched_with_rig": with_rig,
        "max_jaw_open": max(jaw, default=0.0),
        "problems": problems[:20],
    }))
    if problems:
        for p in problems[:20]:
            print(p, file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
