#!/usr/bin/env python3
"""Lip sync accuracy and speed on real speech, no data committed (docs/lipsync.md).

Festival (Debian `festival` + `festvox-kallpc16k`) speaks each sentence to a 16 kHz WAV and
writes its own phone segments: the truth. `mouthpiece lipsync --audio` then makes a take with
the transcript (forced alignment) and without it (phone recognition), and this script
measures against the truth:

- boundary error: the recognised phone sequence is aligned to the truth's by edit distance
  (same phone: cost 0, same viseme class: 0.5, else 1; insertions and deletions 1); for every
  aligned pair, |start - start_truth| and |end - end_truth|; median and p90 over all of them;
- phones matched: aligned pairs with the same class / truth phones;
- dominant class share: output frames whose dominant phone's class (the `class` column of
  `--weights`) is the class of the truth phone at that time;
- shape class share: frames whose weights are nearest (Euclidean) to the truth class's
  target weights (a stricter, shape-only reading: inside change stages the mouth is between
  classes);
- real-time factor: audio seconds / wall seconds of the whole command (model loading
  included), one run per sentence on this machine.

With --speed, instead: the whole command's real-time factor on one long input each: a 60 s
TIMIT phone file (phones cycling through every class, 30-150 ms long) and the sentences
concatenated into one WAV, with and without the transcript (best of 3 runs).

Usage: bench/lipsync_accuracy.py [--bin target/release/mouthpiece] [--sentences sa1,sa2]
       [--json] [--speed]
Standard library only (Python >= 3.11 for tomllib).
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
import tomllib
import wave

REPO = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

SENTENCES = {
    "sa1": "She had your dark suit in greasy wash water all year.",
    "sa2": "Don't ask me to carry an oily rag like that.",
    "s3": "The birch canoe slid on the smooth planks.",
    "s4": "Glue the sheet to the dark blue background.",
    "s5": "It's easy to tell the depth of a well.",
    "s6": "Four hours of steady work faced us.",
    "s7": "A large size in stockings is hard to sell.",
    "s8": "The boy was there when the sun rose.",
}


def load_classes():
    with open(os.path.join(REPO, "config/lipsync/classes.toml"), "rb") as f:
        table = tomllib.load(f)
    poses = table["poses"]
    by_phone, targets = {}, {}
    for c in table["class"]:
        targets[c["name"]] = [c.get("target", {}).get(p, 0.0) for p in poses]
        for p in c["phones"]:
            by_phone[p.lower().rstrip("0123456789")] = c["name"]
    return poses, by_phone, targets


def festival(text, out_dir, name):
    scm = os.path.join(out_dir, name + ".scm")
    wav = os.path.join(out_dir, name + ".wav")
    segs = os.path.join(out_dir, name + ".segs")
    with open(scm, "w") as f:
        f.write(
            f'(set! u (Utterance Text "{text}"))\n(utt.synth u)\n'
            f'(utt.save.wave u "{wav}" \'riff)\n(utt.save.segs u "{segs}")\n'
        )
    subprocess.run(["festival", "-b", scm], check=True, capture_output=True)
    truth, prev, body = [], 0.0, False
    for line in open(segs):
        if not body:
            body = line.strip() == "#"
            continue
        w = line.split()
        if len(w) >= 3:
            end = float(w[0])
            if end > prev:
                truth.append((prev, end, "sil" if w[2] == "pau" else w[2]))
            prev = end
    with wave.open(wav) as w:
        seconds = w.getnframes() / w.getframerate()
    return wav, truth, seconds


def align(rec, truth, cls):
    """Edit-distance alignment of two phone lists; returns the aligned (rec, truth) pairs."""
    n, m = len(rec), len(truth)
    cost = [[0.0] * (m + 1) for _ in range(n + 1)]
    for i in range(1, n + 1):
        cost[i][0] = i
    for j in range(1, m + 1):
        cost[0][j] = j
    def sub(a, b):
        if a[2] == b[2]:
            return 0.0
        return 0.5 if cls(a[2]) == cls(b[2]) else 1.0
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            cost[i][j] = min(
                cost[i - 1][j - 1] + sub(rec[i - 1], truth[j - 1]),
                cost[i - 1][j] + 1,
                cost[i][j - 1] + 1,
            )
    pairs, i, j = [], n, m
    while i > 0 and j > 0:
        if cost[i][j] == cost[i - 1][j - 1] + sub(rec[i - 1], truth[j - 1]):
            pairs.append((rec[i - 1], truth[j - 1]))
            i, j = i - 1, j - 1
        elif cost[i][j] == cost[i - 1][j] + 1:
            i -= 1
        else:
            j -= 1
    return pairs[::-1]


def run_lipsync(binary, wav, transcript, out_dir, tag):
    take = os.path.join(out_dir, tag + ".jsonl")
    weights = os.path.join(out_dir, tag + ".csv")
    phones = os.path.join(out_dir, tag + ".phones.jsonl")
    cmd = [
        binary, "lipsync", "--character", os.path.join(REPO, "config/characters/human.toml"),
        "--audio", wav, "--out", take, "--weights", weights, "--phones-out", phones,
    ]
    if transcript is not None:
        cmd += ["--transcript", transcript]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True, env=dict(os.environ, RUST_LOG="warn"))
    wall = time.perf_counter() - t0
    rec = [(p["start"], p["end"], p["phone"]) for p in map(json.loads, open(phones))]
    rows = []
    with open(weights) as f:
        header = f.readline().strip().split(",")
        for line in f:
            c = line.strip().split(",")
            rows.append((float(c[0]), c[2], [float(x) for x in c[3:]]))
    assert header[:3] == ["t", "phone", "class"], header
    return rec, rows, wall


def measure(binary, names, with_transcript):
    _, by_phone, targets = load_classes()
    cls = lambda p: by_phone.get(p, "?")
    errors, matched, total_truth, dom_ok, shape_ok, frames = [], 0, 0, 0, 0, 0
    audio_s, wall_s = 0.0, 0.0
    with tempfile.TemporaryDirectory() as d:
        for name in names:
            text = SENTENCES[name]
            wav, truth, seconds = festival(text, d, name)
            rec, rows, wall = run_lipsync(binary, wav, text if with_transcript else None, d,
                                          name + ("_t" if with_transcript else "_r"))
            audio_s += seconds
            wall_s += wall
            for a, b in align(rec, truth, cls):
                errors += [abs(a[0] - b[0]), abs(a[1] - b[1])]
                matched += cls(a[2]) == cls(b[2])
            total_truth += len(truth)
            for t, dominant, w in rows:
                truth_phone = next((p for p in truth if p[0] <= t < p[1]), truth[-1])
                tc = cls(truth_phone[2])
                frames += 1
                dom_ok += dominant == tc
                nearest = min(targets, key=lambda c: sum((x - y) ** 2 for x, y in zip(w, targets[c])))
                shape_ok += nearest == tc
    errors.sort()
    p90 = errors[min(len(errors) - 1, int(round(0.9 * (len(errors) - 1))))]
    return {
        "mode": "transcript" if with_transcript else "recognition",
        "sentences": len(names),
        "boundary_median_ms": 1e3 * statistics.median(errors),
        "boundary_p90_ms": 1e3 * p90,
        "phones_matched": matched / total_truth,
        "dominant_class_share": dom_ok / frames,
        "shape_class_share": shape_ok / frames,
        "audio_s": audio_s,
        "wall_s": wall_s,
        "real_time_factor": audio_s / wall_s,
    }


def timed(cmd, runs=3):
    best = float("inf")
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True, env=dict(os.environ, RUST_LOG="warn"))
        best = min(best, time.perf_counter() - t0)
    return best


def speed(binary, names):
    human = os.path.join(REPO, "config/characters/human.toml")
    rows = []
    with tempfile.TemporaryDirectory() as d:
        cycle = ["sh", "iy", "hh", "ae", "d", "y", "er", "aa", "r", "k", "s", "uw", "t", "ih",
                 "n", "g", "z", "w", "ao", "m", "f", "th", "pau", "ow", "ch", "l", "v"]
        phn = os.path.join(d, "long.phn")
        t, i = 0, 0
        with open(phn, "w") as f:
            while t < 60 * 16000:
                n = 480 + (i * 7919) % 1920
                f.write(f"{t} {t + n} {cycle[i % len(cycle)]}\n")
                t, i = t + n, i + 1
        wall = timed([binary, "lipsync", "--character", human, "--phonemes", phn,
                      "--out", os.path.join(d, "p.jsonl")])
        rows.append(("phone file (TIMIT .phn) -> 60 fps take", 60.0, wall))
        frames, rate, texts = b"", 16000, []
        for name in names:
            wav, _, _ = festival(SENTENCES[name], d, name)
            with wave.open(wav) as w:
                rate = w.getframerate()
                frames += w.readframes(w.getnframes())
            texts.append(SENTENCES[name])
        long_wav = os.path.join(d, "long.wav")
        with wave.open(long_wav, "wb") as w:
            w.setnchannels(1)
            w.setsampwidth(2)
            w.setframerate(rate)
            w.writeframes(frames)
        seconds = len(frames) / 2 / rate
        for label, extra in (("audio + transcript (alignment)", ["--transcript", " ".join(texts)]),
                             ("audio, no transcript (recognition)", [])):
            wall = timed([binary, "lipsync", "--character", human, "--audio", long_wav,
                          "--out", os.path.join(d, "a.jsonl")] + extra,
                         runs=3 if extra else 1)
            rows.append((label, seconds, wall))
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", default=os.path.join(REPO, "target/release/mouthpiece"))
    ap.add_argument("--sentences", default=",".join(SENTENCES))
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--modes", default="transcript,recognition")
    ap.add_argument("--speed", action="store_true")
    a = ap.parse_args()
    names = a.sentences.split(",")
    if a.speed:
        print(f"load average before: {os.getloadavg()[0]:.1f}")
        print("| input | length | wall | real time |")
        print("|---|---|---|---|")
        for label, seconds, wall in speed(a.bin, names):
            print(f"| {label} | {seconds:.1f} s | {wall:.3f} s | {seconds / wall:.0f}x |")
        return
    results = [measure(a.bin, names, m == "transcript") for m in a.modes.split(",")]
    if a.json:
        json.dump(results, sys.stdout)
        return
    print("| mode | sentences | boundary median | boundary p90 | phones matched | dominant class | shape class | real time |")
    print("|---|---|---|---|---|---|---|---|")
    for r in results:
        print(
            f"| {r['mode']} | {r['sentences']} | {r['boundary_median_ms']:.1f} ms | "
            f"{r['boundary_p90_ms']:.1f} ms | {100 * r['phones_matched']:.0f} % | "
            f"{100 * r['dominant_class_share']:.1f} % | {100 * r['shape_class_share']:.1f} % | "
            f"{r['real_time_factor']:.1f}x |"
        )


if __name__ == "__main__":
    main()
