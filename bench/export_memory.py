"""Peak memory and time of `mouthpiece export` against the take's length.

Writes synthetic takes (12 points, 30 fps, retarget's line format) of growing length and
exports each to GLB, GLB with --reduce, and CSV, reading each child's peak RSS from wait4.
Constant memory in the number of frames shows as a flat RSS column.

    python bench/export_memory.py [--bin target/release/mouthpiece] [--frames 10000 100000 ...]
"""

import argparse
import math
import os
import subprocess
import tempfile
import time


def write_take(path, frames, points=12):
    with open(path, "w") as f:
        for i in range(frames):
            t = i / 30.0
            o = 0.5 + 0.5 * math.sin(2 * math.pi * 0.7 * t)
            pts = ", ".join(
                f'"P{k + 1}": [{0.025 * math.cos(2 * math.pi * k / points) * (1 - 0.1 * o):.6f}, '
                f"{0.008 * math.sin(2 * math.pi * k / points) * (1 + 1.5 * o):.6f}, "
                f"{0.002 * math.sin(3 * t + k):.6f}]"
                for k in range(points)
            )
            conf = ", ".join(f'"P{k + 1}": 1.0' for k in range(points))
            f.write(
                f'{{"t": {t!r}, "seq": {i}, "character": "human", "points": {{{pts}}}, '
                f'"confidence": {{{conf}}}, "head": {{"rotation": [1.0, 0.0, 0.0, 0.0], '
                f'"translation": [0.0, 0.0, 0.6]}}, "head_lost": false, "curve": null}}\n'
            )


def run(cmd):
    start = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    elapsed = time.monotonic() - start
    err = proc.stderr.read().decode()
    if status != 0:
        raise SystemExit(f"{cmd} failed: {err}")
    return usage.ru_maxrss / 1024.0, elapsed


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", default="target/release/mouthpiece")
    ap.add_argument("--frames", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    args = ap.parse_args()
    print("| frames | take MB | GLB: peak RSS MB, s | GLB --reduce 1e-4: MB, s | CSV: MB, s |")
    print("|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory(dir=".") as d:
        for n in args.frames:
            take = os.path.join(d, "take.jsonl")
            write_take(take, n)
            cells = []
            for out, extra in (("take.glb", []), ("red.glb", ["--reduce", "1e-4"]), ("take.csv", [])):
                rss, secs = run([args.bin, "export", take, "--out", os.path.join(d, out), *extra])
                cells.append(f"{rss:.1f}, {secs:.2f}")
            size = os.path.getsize(take) / 1e6
            print(f"| {n} | {size:.0f} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
