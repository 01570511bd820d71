#!/usr/bin/env python3
"""A minimal mouthpiece.v1 client: prints the character's mouth points as they arrive.

    pip install websockets
    python3 examples/client.py ws://127.0.0.1:9870/ --character wolf --count 100

With tokens (server bound beyond 127.0.0.1): --token <read or control token>.
The protocol is described in docs/protocol.md.
"""

import argparse
import asyncio
import json
import sys
import time

import websockets


async def run(args):
    protocols = ["mouthpiece.v1"]
    if args.token:
        # The token rides along as a second subprotocol entry; the server selects mouthpiece.v1.
        protocols.append("mouthpiece.token." + args.token)
    async with websockets.connect(args.url, subprotocols=protocols, max_size=4 * 1024 * 1024) as ws:
        hello = json.loads(await ws.recv())
        assert hello["type"] == "hello", hello
        names = [c["name"] for c in hello["characters"]]
        print(f"connected to {hello['server']['name']} {hello['server']['version']}: "
              f"characters {', '.join(names)}, {hello['frame_rate']} fps, access {hello['access']}")
        subscribe = {"type": "subscribe", "id": "sub-1"}
        if args.character:
            subscribe["characters"] = [args.character]
        if args.max_rate:
            subscribe["max_rate"] = args.max_rate
        await ws.send(json.dumps(subscribe))
        frames = 0
        last_seq = None
        async for raw in ws:
            msg = json.loads(raw)
            kind = msg["type"]
            if kind == "frame":
                if last_seq is not None and msg["seq"] != last_seq + 1 and not args.max_rate:
                    print(f"  (lost {msg['seq'] - last_seq - 1} frames)")
                last_seq = msg["seq"]
                latency = ""
                if "wall_us" in msg:
                    latency = f" latency {(time.time() * 1e6 - msg['wall_us']) / 1000:.1f} ms"
                for c in msg["characters"]:
                    p = c["points"]
                    print(f"frame {msg['seq']} {msg['timecode']} t={msg['t']:.3f}s {c['name']}: "
                          f"{len(p)} points, P1=({p[0][0]:.3f}, {p[0][1]:.3f}, {p[0][2]:.3f}){latency}")
                frames += 1
                if args.count and frames >= args.count:
                    return 0
            elif kind == "status":
                if "lagged" in msg:
                    print(f"  (server dropped {msg['lagged']} frames: reading too slowly)")
                else:
                    rec = msg["recording"]
                    print(f"status: source {msg['source']}"
                          + (", calibrating" if msg["calibrating"] else "")
                          + (f", recording {rec['slate']} take {rec['take']}" if rec else ""))
            elif kind == "error":
                print(f"error {msg['code']}: {msg['message']}", file=sys.stderr)
            elif kind == "hello":
                print("stream description changed")
    return 0


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("url", nargs="?", default="ws://127.0.0.1:9870/")
    parser.add_argument("--token")
    parser.add_argument("--character", help="only this character")
    parser.add_argument("--max-rate", type=float, help="frames per second at most")
    parser.add_argument("--count", type=int, default=0, help="stop after this many frames")
    args = parser.parse_args()
    try:
        sys.exit(asyncio.run(run(args)))
    except (OSError, websockets.exceptions.WebSocketException) as e:
        print(f"client.py: {args.url}: {e}", file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
