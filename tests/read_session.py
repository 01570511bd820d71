"""Reads a mouthpiece session with Python's `mcap` package (an independent reader) and checks
it against the recording format (docs/recording-format.md).

usage: read_session.py SESSION.mcap EXPECTED.json

EXPECTED.json (written by the Rust test): {"frames": N, "depth_frame": k, "depth_file": path
to the raw little-endian u16 depth of frame k, "width": W, "height": H, "color_format": "jpeg"}
Prints a JSON summary and exits non-zero with a message on the first mismatch.
"""
import json
import struct
import sys

from mcap.reader import make_reader


def fail(msg):
    print(f"FAIL: {msg}", file=sys.stderr)
    sys.exit(1)


class Cdr:
    """Little-endian plain CDR, alignment relative to the end of the 4-byte header."""

    def __init__(self, data):
        if data[0:2] != b"\x00\x01":
            fail(f"CDR representation {data[0:2].hex()} is not little-endian plain CDR")
        self.d = data
        self.p = 4

    def align(self, n):
        self.p += (n - (self.p - 4) % n) % n

    def u32(self):
        self.align(4)
        (v,) = struct.unpack_from("<I", self.d, self.p)
        self.p += 4
        return v

    def i32(self):
        self.align(4)
        (v,) = struct.unpack_from("<i", self.d, self.p)
        self.p += 4
        return v

    def f64(self):
        self.align(8)
        (v,) = struct.unpack_from("<d", self.d, self.p)
        self.p += 8
        return v

    def string(self):
        n = self.u32()
        s = self.d[self.p : self.p + n]
        self.p += n
        if not s.endswith(b"\x00"):
            fail("CDR string without its NUL")
        return s[:-1].decode()

    def octets(self):
        n = self.u32()
        b = self.d[self.p : self.p + n]
        if len(b) != n:
            fail("sequence runs past the end of the message")
        self.p += n
        return b


def raw_image(data):
    c = Cdr(data)
    return {
        "sec": c.i32(), "nanosec": c.u32(), "frame_id": c.string(), "width": c.u32(),
        "height": c.u32(), "encoding": c.string(), "step": c.u32(), "data": c.octets(),
    }


def compressed_image(data):
    c = Cdr(data)
    return {"sec": c.i32(), "nanosec": c.u32(), "frame_id": c.string(), "data": c.octets(), "format": c.string()}


def calibration(data):
    c = Cdr(data)
    out = {"sec": c.i32(), "nanosec": c.u32(), "frame_id": c.string(), "width": c.u32(), "height": c.u32(),
           "distortion_model": c.string()}
    out["D"] = [c.f64() for _ in range(c.u32())]
    out["K"] = [c.f64() for _ in range(9)]
    out["R"] = [c.f64() for _ in range(9)]
    out["P"] = [c.f64() for _ in range(12)]
    return out


def main():
    path, expected_path = sys.argv[1], sys.argv[2]
    expected = json.load(open(expected_path))
    counts = {}
    depth_index = 0
    checked_depth = False
    schemas = {}
    last_log_time = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        if summary is None or summary.statistics is None:
            fail("no summary section with statistics")
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            topic = channel.topic
            counts[topic] = counts.get(topic, 0) + 1
            schemas[topic] = (schema.name if schema else "", schema.encoding if schema else "", channel.message_encoding)
            if message.log_time < last_log_time.get(topic, 0):
                fail(f"{topic}: log_time goes backwards")
            last_log_time[topic] = message.log_time
            if topic == "/camera/depth":
                img = raw_image(message.data)
                if img["encoding"] != "16UC1" or img["step"] != img["width"] * 2:
                    fail(f"depth encoding {img['encoding']} step {img['step']}")
                if (img["width"], img["height"]) != (expected["width"], expected["height"]):
                    fail(f"depth size {img['width']}x{img['height']}")
                # The image's own stamp is the device time; log_time is the capture time (same here).
                if img["sec"] * 10**9 + img["nanosec"] != message.log_time:
                    fail(f"depth stamp {img['sec']}.{img['nanosec']} vs log_time {message.log_time}")
                if depth_index == expected["depth_frame"]:
                    want = open(expected["depth_file"], "rb").read()
                    if img["data"] != want:
                        fail(f"depth of frame {depth_index} differs from what was written")
                    checked_depth = True
                depth_index += 1
            elif topic == "/camera/color":
                img = compressed_image(message.data)
                if img["format"] != expected["color_format"]:
                    fail(f"colour format {img['format']}")
                if not img["data"].startswith(b"\xff\xd8"):
                    fail("colour data is not a JPEG")
            elif topic == "/camera/calibration":
                cal = calibration(message.data)
                if cal["K"][0] <= 0 or (cal["width"], cal["height"]) != (expected["width"], expected["height"]):
                    fail(f"calibration {cal}")
            elif topic == "/groundtruth/points":
                gt = json.loads(message.data)
                for key in ("t", "points", "visible", "head"):
                    if key not in gt:
                        fail(f"ground truth without {key}")
                if set(gt["points"]) != set(gt["visible"]) or len(gt["points"]) != 15:
                    fail(f"ground truth dots {sorted(gt['points'])}")
                if any(len(p) != 3 for p in gt["points"].values()) or len(gt["head"]["rotation"]) != 4:
                    fail("ground truth shapes")
    want_schemas = {
        "/camera/color": ("foxglove_msgs/msg/CompressedImage", "ros2msg", "cdr"),
        "/camera/depth": ("foxglove_msgs/msg/RawImage", "ros2msg", "cdr"),
        "/camera/calibration": ("foxglove_msgs/msg/CameraCalibration", "ros2msg", "cdr"),
        "/groundtruth/points": ("mouthpiece.GroundTruth", "jsonschema", "json"),
    }
    for topic, want in want_schemas.items():
        if schemas.get(topic) != want:
            fail(f"{topic}: schema/encodings {schemas.get(topic)}, expected {want}")
    n = expected["frames"]
    for topic in ("/camera/color", "/camera/depth", "/groundtruth/points"):
        if counts.get(topic) != n:
            fail(f"{topic}: {counts.get(topic)} messages, expected {n}")
    if not checked_depth:
        fail("the depth frame to compare was not found")
    if "mouthpiece.calibration" not in meta or "mouthpiece.session" not in meta:
        fail(f"metadata records {sorted(meta)}")
    cal = json.loads(meta["mouthpiece.calibration"]["calibration"])
    if abs(cal["depth_scale_m"] - 0.001) > 1e-12 or "depth_to_color" not in cal:
        fail(f"calibration metadata {cal}")
    stats = summary.statistics
    if stats.message_count != sum(counts.values()):
        fail(f"statistics count {stats.message_count} vs {sum(counts.values())} read")
    # If the ROS 2 decoder is installed (CI installs it), it must decode our schemas too: an
    # independent parser of the ros2msg text.
    ros2 = None
    try:
        from mcap_ros2.decoder import DecoderFactory
        ros2 = DecoderFactory()
    except ImportError:
        pass
    if ros2 is not None:
        with open(path, "rb") as f:
            reader = make_reader(f, decoder_factories=[ros2])
            seen = set()
            for schema, channel, message, decoded in reader.iter_decoded_messages(
                topics=["/camera/depth", "/camera/color", "/camera/calibration"]
            ):
                if channel.topic == "/camera/depth" and decoded.encoding != "16UC1":
                    fail("mcap_ros2 decodes a different depth encoding")
                if channel.topic == "/camera/calibration" and len(decoded.k) != 9:
                    fail("mcap_ros2 decodes a different calibration")
                seen.add(channel.topic)
                if len(seen) == 3:
                    break
    print(json.dumps({"counts": counts, "ros2_decoder": ros2 is not None, "metadata": sorted(meta)}))


if __name__ == "__main__":
    main()
