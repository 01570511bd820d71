"""The sound–picture offset of a take made from a replayed session whose sound and frames share
one timeline (`mouthpiece synth --speech W --speech-audio WAV`): how much later (ms) the take
stamps the sound than the picture, relative to the session.

usage: sound_picture_offset.py SESSION.mcap TAKE.mcap
Frames are matched by their device timestamp (kept through replay), sound blocks by content.
Prints JSON: {"offset_ms", "sound_delay_ms", "picture_delay_ms", "frames", "blocks"}.
"""

import json
import sys

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def read(path):
    frames, blocks = {}, {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(
            topics=["/camera/color", "/audio"], log_time_order=True
        ):
            if channel.topic == "/camera/color":
                device_ns = decoded.timestamp.sec * 10**9 + decoded.timestamp.nanosec
                frames.setdefault(device_ns, message.log_time)
            else:
                blocks.setdefault(bytes(decoded.data), message.log_time)
    return frames, blocks


session_frames, session_blocks = read(sys.argv[1])
take_frames, take_blocks = read(sys.argv[2])
picture = [take_frames[k] - session_frames[k] for k in take_frames if k in session_frames]
# Blocks of silence repeat: only blocks whose content is unique in the session count.
sound = [take_blocks[k] - session_blocks[k] for k in take_blocks
         if k in session_blocks and any(k)]
assert len(picture) >= 10 and len(sound) >= 10, (len(picture), len(sound))
picture_delay = float(np.median(picture)) / 1e6
sound_delay = float(np.median(sound)) / 1e6
print(json.dumps({
    "offset_ms": sound_delay - picture_delay,
    "sound_delay_ms": sound_delay,
    "picture_delay_ms": picture_delay,
    "frames": len(picture),
    "blocks": len(sound),
}))
