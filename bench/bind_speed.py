"""Time and memory of `mouthpiece bind` per method: a 50k-vertex head by default (target
≤ 10 s on one core), `--resolution 58` for the 203k-vertex one (target ≤ 30 s, ≤ 2 GB).

Writes a procedural head around the human's mouth (`bind head --resolution 29`: 51 156
vertices) and binds it with each method, `--repeat` times, reading each child's CPU time
(user + system, from wait4) and wall time. On a shared machine the CPU time is the fair
figure; the load average is printed with the results.

    python bench/bind_speed.py [--bin target/release/mouthpiece] [--repeat 3] [--resolution 58]
"""

import argparse
import os
import subprocess
import tempfile
import time


def run(cmd):
    start = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.monotonic() - start
    err = proc.stderr.read().decode()
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{err}")
    return usage.ru_utime + usage.ru_stime, wall, usage.ru_maxrss / 1024.0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", default="target/release/mouthpiece")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--resolution", default="29")
    ap.add_argument("--character", default="config/characters/human.toml")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        head = os.path.join(tmp, "head.glb")
        run([args.bin, "bind", "head", "--character", args.character, "--resolution", args.resolution, "--out", head])
        print(f"load average {os.getloadavg()[0]:.1f}")
        print("| method | CPU median (s) | wall median (s) | peak memory (MiB) |")
        print("|---|---:|---:|---:|")
        for method in ["network", "heat", "distance"]:
            out = os.path.join(tmp, f"{method}.glb")
            times = [
                run([args.bin, "bind", "--character", args.character, "--mesh", head, "--method", method, "--out", out])
                for _ in range(args.repeat)
            ]
            cpu = sorted(t[0] for t in times)[len(times) // 2]
            wall = sorted(t[1] for t in times)[len(times) // 2]
            peak = max(t[2] for t in times)
            print(f"| {method} | {cpu:.2f} | {wall:.2f} | {peak:.0f} |")
        print(f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
