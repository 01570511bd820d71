"""Checks a take's sound with Foxglove's own MCAP reader and ROS 2 decoder, and its exported
Broadcast WAV with Python's `wave` + numpy.

usage: check_take_audio.py TAKE.mcap SPEECH.s16 [EXPORT.wav]
Prints one JSON object with what it found; asserts what must hold.
"""

import json
import struct
import sys
import wave

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

take, speech_path = sys.argv[1], sys.argv[2]
wav_path = sys.argv[3] if len(sys.argv) > 3 else None
speech = np.fromfile(speech_path, dtype="<i2")

blocks, frames, events = [], [], []
with open(take, "rb") as f:
    reader = make_reader(f, decoder_factories=[DecoderFactory()])
    meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    for schema, channel, message, decoded in reader.iter_decoded_messages(
        topics=["/audio"], log_time_order=True
    ):
        assert schema.name == "foxglove_msgs/msg/RawAudio", schema.name
        assert decoded.format == "pcm-s16", decoded.format
        stamp = decoded.timestamp.sec * 10**9 + decoded.timestamp.nanosec
        assert stamp == message.log_time, (stamp, message.log_time)
        blocks.append(
            (message.log_time, decoded.sample_rate, decoded.number_of_channels,
             np.frombuffer(bytes(decoded.data), dtype="<i2"))
        )
    f.seek(0)
    reader = make_reader(f)
    for schema, channel, message in reader.iter_messages(
        topics=["/camera/color", "/audio/events"], log_time_order=True
    ):
        if channel.topic == "/camera/color":
            frames.append(message.log_time)
        else:
            events.append(json.loads(message.data))

assert blocks, "no /audio"
assert all(b[1] == 48000 and b[2] == 1 for b in blocks)
sound = np.concatenate([b[3] for b in blocks])
# The take's sound is a contiguous stretch of the speech, bit for bit (zeros past its end):
# find the lag by cross-correlation, then compare every sample.
padded = np.concatenate([speech, np.zeros(len(sound), dtype="<i2")])
n = len(padded) + len(sound)
size = 1 << (n - 1).bit_length()
corr = np.fft.irfft(
    np.fft.rfft(padded.astype(float), size) * np.conj(np.fft.rfft(sound.astype(float), size)),
    size,
)
lag = int(np.argmax(corr[: len(padded)]))
exact = bool(np.array_equal(padded[lag : lag + len(sound)], sound))
# Blocks follow each other without gaps: each starts where the previous one ended.
steps = [
    (b[0] - a[0]) - len(a[3]) * 10**9 / 48000 for a, b in zip(blocks, blocks[1:])
]
out = {
    "blocks": len(blocks),
    "samples": int(len(sound)),
    "lag": lag,
    "exact": exact,
    "max_step_error_ms": float(np.max(np.abs(steps)) / 1e6) if steps else 0.0,
    "frames": len(frames),
    "first_frame": frames[0] if frames else None,
    "last_frame": frames[-1] if frames else None,
    "first_audio": blocks[0][0],
    "events": events,
    "audio_meta": meta.get("mouthpiece.audio"),
}

if wav_path:
    with wave.open(wav_path, "rb") as w:
        rate, channels, width, length = (
            w.getframerate(), w.getnchannels(), w.getsampwidth(), w.getnframes())
        data = np.frombuffer(w.readframes(length), dtype="<i2")
    raw = open(wav_path, "rb").read()
    at = raw.index(b"bext") + 8
    low, high = struct.unpack_from("<II", raw, at + 338)
    period = (frames[-1] - frames[0]) / (len(frames) - 1)
    # The WAV laid out again here by the documented rule: sample 0 at the first frame (sound
    # before it cut); a block within 40 ms of where the one before it ended continues it,
    # any other starts at the sample nearest its time (rounded half away from zero).
    def nearest_sample(log_time):
        off = (log_time - frames[0]) * 48000
        q = (abs(off) + 500_000_000) // 10**9
        return q if off >= 0 else -q

    tolerance = 40 * 48000 // 1000
    expected = np.zeros(length, dtype="<i2")
    end, worst = None, 0
    for log_time, _, _, samples in blocks:
        at = nearest_sample(log_time)
        first = end if end is not None and abs(at - end) <= tolerance else at
        worst = max(worst, abs(first - at))
        end = first + len(samples)
        lo, hi = max(first, 0), min(end, length)
        if lo < hi:
            expected[lo:hi] = samples[lo - first : hi - first]
    out["wav"] = {
        "rate": rate,
        "channels": channels,
        "width": width,
        "length": length,
        "expected_length": int(np.ceil((frames[-1] - frames[0] + period) * 48000 / 1e9)),
        "time_reference": (high << 32) | low,
        "expected_time_reference": (frames[0] // 1000 % 86_400_000_000) * 48000 // 1_000_000,
        "laid_out_as_documented": bool(np.array_equal(data, expected)),
        "max_placement_error_ms": worst / 48.0,
    }
print(json.dumps(out))
