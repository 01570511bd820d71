#!/usr/bin/env python3
"""Synthetic performer for mouthpiece's retarget tests: raw 3D dots in the camera frame.

A head with 12 painted lip dots and 3 forehead dots faces an OpenCV camera (x right, y down,
z forward, metres) at about 0.6 m, holds still with the mouth closed for the neutral second,
then talks (mouth opening, lip rounding, protrusion) while the head turns and moves. Dots get
Gaussian noise; some lip dots drop out; optionally a forehead dot drops out (head lost when
fewer than 3 remain) and the neutral block gets an outlier.

    python3 performer.py --seed 7 --seconds 4 --out performer.jsonl

Deterministic for a given seed (numpy's PCG64).
"""

import argparse
import json
import sys

import numpy as np

# Head-local frame of the performer: x towards the performer's left, y up, z out of the face.
# Lip dots D1..D12: D1 left corner, D2..D6 upper lip left to right, D7 right corner, D8..D12
# lower lip right to left. Metres.
LIPS = np.array([
    [0.025, 0.0, 0.0],
    [0.0210, 0.0050, 0.0040], [0.0120, 0.0085, 0.0075], [0.0, 0.0075, 0.0090],
    [-0.0120, 0.0085, 0.0075], [-0.0210, 0.0050, 0.0040],
    [-0.025, 0.0, 0.0],
    [-0.0210, -0.0055, 0.0030], [-0.0120, -0.0095, 0.0065], [0.0, -0.0105, 0.0080],
    [0.0120, -0.0095, 0.0065], [0.0210, -0.0055, 0.0030],
])
FOREHEAD = np.array([[-0.035, 0.095, -0.020], [0.035, 0.095, -0.020], [0.0, 0.115, -0.025]])
# Head-local → camera axes (performer faces the camera).
TO_CAMERA = np.diag([1.0, -1.0, -1.0])


def rotation(yaw, pitch, roll):
    """Rotation about the head's y (yaw), x (pitch), z (roll) axes, head-local."""
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return ry @ rx @ rz


def generate(seed, seconds=4.0, fps=30.0, neutral_seconds=1.0, noise=0.0003, head="moderate",
             dropout=0.02, forehead_dropout=True, outlier=True, lip_count=12, decimals=6,
             flag_neutral=True):
    """The performer's lines (dicts). `decimals=None` keeps full float precision."""
    rnd = (lambda v: round(float(v), decimals)) if decimals is not None else float
    rng = np.random.default_rng(seed)
    lips = LIPS * rng.uniform(0.85, 1.2) + rng.normal(0, 0.0008, LIPS.shape)
    lips[0] = [abs(lips[0][0]), 0.0, 0.0]
    lips[6] = [-abs(lips[6][0]), 0.0, 0.0]
    forehead = FOREHEAD + rng.normal(0, 0.004, FOREHEAD.shape)
    pivot = np.array([0.0, 0.03, -0.09])  # neck-ish pivot behind the mouth
    base = np.array([rng.uniform(-0.05, 0.05), rng.uniform(0.0, 0.08), rng.uniform(0.5, 0.8)])
    amp = {"none": 0.0, "moderate": 1.0, "strong": 2.0}[head]
    phases = rng.uniform(0, 2 * np.pi, 8)
    freqs = rng.uniform(0.2, 0.9, 8)
    syllable = rng.uniform(3.0, 5.0)
    n_frames = int(round(seconds * fps))
    n_neutral = int(round(neutral_seconds * fps))
    lost_start = int(n_frames * 0.7)
    lines = []
    for i in range(n_frames):
        t = i / fps
        neutral = i < n_neutral
        if neutral:
            yaw = pitch = roll = 0.0
            shift = np.zeros(3)
            shape = lips.copy()
        else:
            s = t - neutral_seconds
            yaw = amp * np.radians(12) * np.sin(2 * np.pi * freqs[0] * s + phases[0])
            pitch = amp * np.radians(7) * np.sin(2 * np.pi * freqs[1] * s + phases[1])
            roll = amp * np.radians(5) * np.sin(2 * np.pi * freqs[2] * s + phases[2])
            shift = amp * np.array([
                0.03 * np.sin(2 * np.pi * freqs[3] * s + phases[3]),
                0.02 * np.sin(2 * np.pi * freqs[4] * s + phases[4]),
                0.04 * np.sin(2 * np.pi * freqs[5] * s + phases[5]),
            ])
            opening = 0.012 * max(0.0, np.sin(2 * np.pi * syllable * s)) ** 1.5
            rounding = 0.5 + 0.5 * np.sin(2 * np.pi * freqs[6] * s + phases[6])
            shape = lips.copy()
            upper = slice(1, 6)
            lower = slice(7, 12)
            shape[upper, 1] += 0.25 * opening
            shape[lower, 1] -= opening * (1.0 - np.abs(shape[lower, 0]) / 0.03)
            shape[:, 0] *= 1.0 - 0.2 * rounding * (opening / 0.012 + 0.3)
            shape[:, 2] += 0.004 * rounding * (1.0 - np.abs(shape[:, 0]) / 0.03)
        r = rotation(yaw, pitch, roll)
        to_cam = lambda p: ((r @ (p - pivot).T).T + pivot + shift) @ TO_CAMERA.T + base
        lip_cam = to_cam(shape[:lip_count]) + rng.normal(0, noise, (lip_count, 3))
        fh_cam = to_cam(forehead) + rng.normal(0, noise, forehead.shape)
        if neutral and outlier and i == n_neutral // 2:
            lip_cam[3] += [0.01, -0.02, 0.015]  # a mislabelled blob, once
        points = {}
        for k in range(lip_count):
            seen = neutral or rng.random() > dropout
            points[f"D{k + 1}"] = [rnd(v) for v in lip_cam[k]] if seen else None
        for k in range(3):
            seen = True
            if forehead_dropout and not neutral:
                if k == 2 and i % 11 == 5:
                    seen = False  # one of three gone: head lost for that frame
                if k < 2 and lost_start <= i < lost_start + 4:
                    seen = False
            points[f"F{k + 1}"] = [rnd(v) for v in fh_cam[k]] if seen else None
        line = {"t": rnd(t), "points": points}
        if neutral and flag_neutral:
            line["neutral"] = True
        lines.append(line)
    return lines


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--head", choices=["none", "moderate", "strong"], default="moderate")
    ap.add_argument("--noise", type=float, default=0.0003, help="dot noise, metres (sigma)")
    ap.add_argument("--dropout", type=float, default=0.02, help="lip dot dropout probability")
    ap.add_argument("--no-forehead-dropout", action="store_true")
    ap.add_argument("--no-outlier", action="store_true")
    ap.add_argument("--full-precision", action="store_true", help="do not round to 1 µm")
    ap.add_argument("--out", default="-")
    a = ap.parse_args()
    lines = generate(a.seed, a.seconds, a.fps, noise=a.noise, head=a.head, dropout=a.dropout,
                     forehead_dropout=not a.no_forehead_dropout, outlier=not a.no_outlier,
                     decimals=None if a.full_precision else 6)
    out = sys.stdout if a.out == "-" else open(a.out, "w")
    for line in lines:
        out.write(json.dumps(line, separators=(",", ":")) + "\n")


if __name__ == "__main__":
    main()
