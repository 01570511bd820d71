#!/usr/bin/env python3
"""A NATS subscriber for a mouthpiece booth (docs/nats.md), with nats-py.

Asks the booth for its `hello` (request/reply), then prints each frame's sequence number,
stream time and latency (booth -> here, from the Mouthpiece-Sent-Us header) and every
character's jaw opening from its rig, until --frames frames have arrived. The last line is
a JSON summary. With --record SLATE it records a take over request/reply first (needs a NATS
user allowed to publish on mouthpiece.<booth>.control).

    pip install nats-py
    python3 examples/nats_subscriber.py --server nats://127.0.0.1:4222 --booth booth-a

The password, if any, comes from the environment variable MOUTHPIECE_NATS_PASSWORD.
"""

import argparse
import asyncio
import json
import os
import sys
import time

import nats


async def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--server", default="nats://127.0.0.1:4222")
    parser.add_argument("--booth", required=True)
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--user")
    parser.add_argument("--record", metavar="SLATE")
    parser.add_argument("--timeout", type=float, default=30.0)
    args = parser.parse_args()

    options = {}
    if args.user:
        options = {"user": args.user, "password": os.environ.get("MOUTHPIECE_NATS_PASSWORD", "")}
    nc = await nats.connect(args.server, connect_timeout=5, max_reconnect_attempts=-1, **options)
    prefix = f"mouthpiece.{args.booth}"

    hello = json.loads((await nc.request(f"{prefix}.hello", b"", timeout=5)).data)
    characters = [c["name"] for c in hello["characters"]]
    print(f"hello: {hello['server']['name']} {hello['server']['version']}, characters {', '.join(characters)}")

    if args.record:
        request = {"type": "record", "action": "start", "slate": args.record, "id": 1}
        reply = json.loads((await nc.request(f"{prefix}.control", json.dumps(request).encode(), timeout=10)).data)
        print(f"record: {reply['type']}")

    frames = asyncio.Queue()

    async def on_frame(msg):
        sent_us = int(msg.headers.get("Mouthpiece-Sent-Us", "0")) if msg.headers else 0
        await frames.put((json.loads(msg.data), sent_us, time.time()))

    await nc.subscribe(f"{prefix}.frame", cb=on_frame)
    latencies = []
    seqs = []
    deadline = time.monotonic() + args.timeout
    while len(seqs) < args.frames:
        left = deadline - time.monotonic()
        if left <= 0:
            break
        try:
            frame, sent_us, received = await asyncio.wait_for(frames.get(), timeout=left)
        except asyncio.TimeoutError:
            break
        latency_ms = (received * 1e6 - sent_us) / 1e3 if sent_us else float("nan")
        latencies.append(latency_ms)
        seqs.append(frame["seq"])
        jaws = []
        for c in frame["characters"]:
            rig = c.get("rig")
            if rig is not None:
                jaws.append(f"{c['name']} jawOpen {rig['curves']['jawOpen']:.3f}")
        print(f"seq {frame['seq']} t {frame['t']:.3f} latency {latency_ms:.2f} ms {'; '.join(jaws)}")

    if args.record:
        request = {"type": "record", "action": "stop", "id": 2}
        reply = json.loads((await nc.request(f"{prefix}.control", json.dumps(request).encode(), timeout=30)).data)
        print(f"stop: {reply['type']}")
    await nc.drain()
    latencies.sort()
    summary = {
        "frames": len(seqs),
        "characters": characters,
        "in_order": seqs == sorted(seqs),
        "latency_p50_ms": latencies[len(latencies) // 2] if latencies else None,
    }
    print(json.dumps(summary))
    return 0 if len(seqs) >= args.frames else 1


if __name__ == "__main__":
    sys.exit(asyncio.run(main()))
