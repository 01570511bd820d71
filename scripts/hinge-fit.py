#!/usr/bin/env python3
"""Hinge fits tried for the rig's jaw (docs/rig.md, "Other hinges and a sliding jaw").

Reads `mouthpiece evaluate --rig-frames FILE` CSVs and, per session and for the tracked and
the true dots, prints the jaw's RMS error (degrees, against the synthetic jaw) with the rig's
fixed default hinge and with a hinge fitted from the first 4 s of counted frames by:
circle (a circle through the neutral lower-lip centroid fitted to its path), rotation (the
lower lip's own rotation and its centroid's motion) and radius (the default's direction, the
distance by reverse regression on the lower lip's rotation).

    scripts/hinge-fit.py FILE.csv...
"""
import csv
import sys

import numpy as np

UPPER, LOWER = list(range(1, 6)), list(range(7, 12))
LEARN_S = 4.0


def sessions(path):
    rows = {}
    for r in csv.DictReader(open(path)):
        rows.setdefault((r["seed"], r["noise"], r["head_motion"]), []).append(r)
    for key, rs in rows.items():
        def dots(side):
            return np.array([[[float(r[f"{side}_D{i + 1}_{a}"]) for a in "xyz"]
                              for i in range(12)] for r in rs])
        yield key, dict(t=np.array([float(r["t"]) for r in rs]),
                        jaw=np.array([float(r["true_jaw_deg"]) for r in rs]),
                        tracked=(dots("tracked"), dots("tracked_neutral")[0]),
                        reference=(dots("reference"), dots("reference_neutral")[0]))


def motions(lip, n0):
    d = lip - n0
    return d[:, UPPER].mean(1), d[:, LOWER].mean(1), n0[LOWER].mean(0)


def angle_deg(lip, n0, h):
    """The rig's jaw angle about the pivot h = (y, z) (docs/rig.md, *The jaw*)."""
    du, dl, c0 = motions(lip, n0)
    r0y, r0z = c0[1] - h[0], c0[2] - h[1]
    py, pz = r0y + dl[:, 1], r0z + dl[:, 2] - du[:, 2]
    return np.degrees(np.arctan2(r0y * pz - r0z * py, r0y * py + r0z * pz))


def lower_rotation(n0, lip):
    """The lower lip's rigid rotation about the hinge axis (x), radians (Kabsch)."""
    p, q = n0[LOWER] - n0[LOWER].mean(0), lip[LOWER] - lip[LOWER].mean(0)
    u, _, vt = np.linalg.svd(p.T @ q)
    r = vt.T @ np.diag([1, 1, np.sign(np.linalg.det(vt.T @ u.T))]) @ u.T
    return np.arctan2(r[2, 1], r[1, 1])


def fits(lip, n0, learn):
    w = np.linalg.norm(n0[0] - n0[6])
    du, dl, c0 = motions(lip, n0)
    c = c0[1:]
    default = np.array([0.5 * w, -1.6 * w])
    q = np.stack([dl[learn, 1], dl[learn, 2] - du[learn, 2]], 1)  # lower-lip centroid motion
    # Circle through c0: |c + q − h|² = |c − h|²  →  2 q·h = 2 q·c + |q|².
    circle, *_ = np.linalg.lstsq(2 * q, 2 * q @ c + (q * q).sum(1), rcond=None)
    th = np.array([lower_rotation(n0, lip[k]) for k in np.nonzero(learn)[0]])
    rows = [np.array([[np.cos(a) - 1, -np.sin(a)], [np.sin(a), np.cos(a) - 1]]) for a in th]
    rotation, *_ = np.linalg.lstsq(np.concatenate(rows),
                                   np.concatenate([m @ c - d for m, d in zip(rows, q)]),
                                   rcond=None)
    dist = np.hypot(q[:, 0], q[:, 1]) * np.sign(-q[:, 0])
    u = (default - c) / np.linalg.norm(default - c)
    radius = c + (dist @ dist) / (th @ dist) * u
    return w, dict(default=default, circle=circle, rotation=rotation, radius=radius)


def main(paths):
    for path in paths:
        for key, s in sessions(path):
            learn = s["t"] < s["t"][0] + LEARN_S
            for side in ("tracked", "reference"):
                lip, n0 = s[side]
                w, hs = fits(lip, n0, learn)
                cells = []
                for name, h in hs.items():
                    e = np.sqrt(np.mean((angle_deg(lip, n0, h) - s["jaw"]) ** 2))
                    cells.append(f"{name} ({h[0] / w:+.2f} up, {-h[1] / w:.2f} back) w {e:.2f}°")
                print(f"{path} | {' '.join(key)} | {side} | " + " | ".join(cells))


if __name__ == "__main__":
    main(sys.argv[1:])
