#!/usr/bin/env python3
"""Capture -> page latency of the booth console with 1, 16 and 64 clients.

Starts `mouthpiece run` (the embedded default: the demo session replayed at real-time pace,
human and wolf) for each client count, opens the console page in headless Chromium (Debian's
`chromium` + `chromium-driver`, driven over WebDriver's HTTP API with the standard library),
adds N - 1 other clients with `mouthpiece-loadgen --url`, and after a warm-up reads the
page's own per-frame latencies (browser clock - the frame's `wall_us`) and the loadgen's.
The page also asks for the camera preview (10 images/s), as it always does.

    cargo build --release -p mouthpiece -p mouthpiece-server
    python3 bench/console_latency.py --bin target/release [--seconds 20] [--clients 1,16,64]

Run from the repository root (the demo session is `recordings/demo.mcap`). Prints a Markdown
table row per client count.
"""

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_port(port, limit=30.0):
    deadline = time.time() + limit
    while time.time() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
            return
        except OSError:
            time.sleep(0.1)
    raise SystemExit(f"nothing listens on {port}")


class WebDriver:
    def __init__(self, profile):
        self.port = free_port()
        self.proc = subprocess.Popen(["chromedriver", f"--port={self.port}"],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wait_port(self.port)
        caps = {"capabilities": {"alwaysMatch": {"browserName": "chrome", "goog:chromeOptions": {
            "binary": "/usr/bin/chromium",
            "args": ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                     "--no-first-run", "--disable-background-networking",
                     "--disable-component-update", "--disable-sync", "--disable-dev-shm-usage",
                     "--window-size=1024,768", f"--user-data-dir={profile}"]}}}}
        self.session = self.call("POST", "/session", caps)["sessionId"]

    def call(self, method, path, body=None):
        data = json.dumps(body).encode() if body is not None else None
        req = urllib.request.Request(f"http://127.0.0.1:{self.port}{path}", data=data,
                                     method=method, headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(req, timeout=60) as r:
            return json.loads(r.read())["value"]

    def open(self, url):
        self.call("POST", f"/session/{self.session}/url", {"url": url})

    def script(self, js):
        return self.call("POST", f"/session/{self.session}/execute/sync", {"script": js, "args": []})

    def close(self):
        try:
            self.call("DELETE", f"/session/{self.session}")
        finally:
            self.proc.kill()
            self.proc.wait()


def pct(values, q):
    values = sorted(values)
    return values[min(len(values) - 1, int(q * len(values)))]


def run(bin_dir, clients, seconds):
    port = free_port()
    work = tempfile.mkdtemp(prefix="mp-latency-")
    config = os.path.join(work, "mouthpiece.toml")
    demo = os.path.abspath("recordings/demo.mcap")
    with open(config, "w") as f:
        f.write(f'[source]\nspec = "replay:{demo}?loop=1&speed=1.0"\n'
                f'[server]\nlisten = "127.0.0.1:{port}"\nmax_clients = 128\n'
                f'[takes]\nfolder = "{work}/takes"\n')
    daemon = subprocess.Popen([os.path.join(bin_dir, "mouthpiece"), "run", "--config", config],
                              stdout=subprocess.DEVNULL, stderr=open(os.path.join(work, "log"), "w"))
    driver = None
    loadgen = None
    try:
        wait_port(port)
        driver = WebDriver(os.path.join(work, "profile"))
        driver.open(f"http://127.0.0.1:{port}/")
        if clients > 1:
            loadgen = subprocess.Popen(
                [os.path.join(bin_dir, "mouthpiece-loadgen"), "--url", f"ws://127.0.0.1:{port}/",
                 "--clients", str(clients - 1), "--stalled", "0", "--seconds", str(seconds + 6),
                 "--max-p99-ms", "1000"],
                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        time.sleep(5)  # warm-up: connections, calibration, preview encoder
        driver.script("window.mouthpiece.latencyLog.length = 0; return null;")
        time.sleep(seconds)
        page = driver.script("const m = window.mouthpiece; return {lat: m.latencyLog, "
                             "images: m.preview.images, health: m.health};")
        report = None
        if loadgen:
            out, _ = loadgen.communicate(timeout=seconds + 60)
            report = json.loads(out[out.index("{"):]) if "{" in out else None
        metrics = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10).read().decode()
        return page, report, metrics
    finally:
        if loadgen and loadgen.poll() is None:
            loadgen.kill()
        if driver:
            driver.close()
        daemon.terminate()
        daemon.wait()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", default="target/release")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--clients", default="1,16,64")
    args = ap.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.1f}", file=sys.stderr)
    print("| clients | page frames | page p50 (ms) | page p99 (ms) | page max (ms) | other clients p50 / p99 (ms) | preview images | daemon processing (ms) | load avg |")
    print("|---|---|---|---|---|---|---|---|---|")
    for n in [int(x) for x in args.clients.split(",")]:
        page, report, metrics = run(args.bin, n, args.seconds)
        lat = page["lat"]
        if not lat:
            raise SystemExit(f"{n} clients: the page received no frames")
        others = "–"
        if report and "latency_ms" in report:
            others = f"{report['latency_ms']['p50_ms']:.2f} / {report['latency_ms']['p99_ms']:.2f}"
        health = page.get("health") or {}
        print(f"| {n} | {len(lat)} | {statistics.median(lat):.1f} | {pct(lat, 0.99):.1f} | "
              f"{max(lat):.1f} | {others} | {page['images']} | "
              f"{health.get('processing_ms', float('nan')):.2f} | {os.getloadavg()[0]:.1f} |", flush=True)


if __name__ == "__main__":
    main()
