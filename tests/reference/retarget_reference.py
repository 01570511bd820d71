#!/usr/bin/env python3
"""Independent reference of mouthpiece's retarget (docs/method.md §2–§6, §8), in numpy/scipy.

Written from the method text, not from the Rust code, to check `mouthpiece retarget`:

    python3 retarget_reference.py --character wolf.toml --input in.jsonl --out out.jsonl \
        [--smooth none|ma|ma-weighted|ma-exp|sg5|bspline] [--hold 0.5] [--decay 0.5]

Head motion is removed with scipy's Rotation.align_vectors (a different algorithm from the
Rust SVD); smoothing uses scipy.signal.savgol_filter and scipy.interpolate.BSpline.
"""

import argparse
import json
import re
import sys
import tomllib

import numpy as np
from scipy.interpolate import BSpline
from scipy.signal import savgol_filter
from scipy.spatial.transform import Rotation

import rig_reference


# ---------------------------------------------------------------- character (§2, §7)

def mouth_frame(left, right, up):
    """Origin, 3x3 axes (columns x, y, z in the parent frame), width."""
    x = left - right
    width = np.linalg.norm(x)
    x = x / width
    y = up - np.dot(up, x) * x
    y = y / np.linalg.norm(y)
    z = np.cross(x, y)
    return (left + right) / 2, np.column_stack([x, y, z]), width


def arc_length_points(polyline, count):
    polyline = np.asarray(polyline, float)
    seg = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
    s = np.concatenate([[0], np.cumsum(seg)])
    targets = np.linspace(0, s[-1], count)
    return np.column_stack([np.interp(targets, s, polyline[:, k]) for k in range(3)])


def load_character(path):
    with open(path, "rb") as f:
        doc = tomllib.load(f)
    if "contour" in doc:
        c = doc["contour"]
        k = c["points_per_lip"]
        upper = arc_length_points(c["upper"], k)
        lower = arc_length_points(c["lower"], k)
        pts = np.vstack([upper, lower[1:k - 1][::-1]])
        names = [f"P{i + 1}" for i in range(len(pts))]
    else:
        names = list(doc["points"].keys())  # tomllib keeps document order
        # Names P1..PN (in any order) place the points by number; other names keep the
        # document's order and need a [map].
        if sorted(names) == sorted(f"P{i + 1}" for i in range(len(names))):
            names = [f"P{i + 1}" for i in range(len(names))]
        pts = np.array([doc["points"][n] for n in names], float)
    n = len(names)
    if "map" in doc:
        driver = [None] * n
        for dot, point in doc["map"].items():
            driver[names.index(point)] = int(dot[1:]) - 1
    else:
        driver = list(range(n))
    left = driver.index(0)
    right = driver.index(n // 2)
    up = np.array(doc.get("up", [0.0, 1.0, 0.0]), float)
    origin, axes, width = mouth_frame(pts[left], pts[right], up)
    p0 = (pts - origin) @ axes
    p0[np.abs(p0) <= 1e-9 * width] = 0.0  # rounding noise where the file means an exact 0
    mode = doc.get("m_mode", "per-point")
    manual = np.array([doc["m"][nm] for nm in names], float) if mode == "manual" else None
    return dict(name=doc["name"], names=names, p0=p0, driver=np.array(driver), mode=mode,
                manual=manual, width=width)


# ---------------------------------------------------------------- neutral (§3)

def robust_mean(samples):
    samples = np.asarray(samples, float)
    med = np.median(samples, axis=0)
    mad = np.median(np.abs(samples - med), axis=0)
    keep = np.all(np.abs(samples - med) <= 3 * mad, axis=1)
    if not keep.any():
        return med
    return samples[keep].mean(axis=0)


def spans_plane(points):
    points = np.asarray(points, float)
    return len(points) >= 3 and np.linalg.matrix_rank(points - points.mean(axis=0), tol=1e-9) >= 2


def neutral_pose(frames, n, n_fh):
    """§3 with the head registered: each frame's forehead is fitted rigidly onto the robust
    mean forehead and the whole frame carried along (twice), then every dot is averaged."""
    def split(frame):
        lip, fh = [None] * n, [None] * n_fh
        for k, v in frame.items():
            if v is not None:
                kind, i = dot_index(k)
                (lip if kind == "D" else fh)[i] = np.array(v, float)
        return lip, fh

    def mean_forehead(frames):
        return [robust_mean(s) if (s := [f[1][j] for f in frames if f[1][j] is not None]) else None
                for j in range(n_fh)]

    raw = [split(l["points"]) for l in frames]
    registered = raw
    reference = mean_forehead(registered)
    for _ in range(2):
        if not spans_plane([r for r in reference if r is not None]):
            break
        registered = []
        for lip, fh in raw:
            pairs = [(c, r) for c, r in zip(fh, reference) if c is not None and r is not None]
            cur = np.array([c for c, _ in pairs]).reshape(-1, 3)
            ref = np.array([r for _, r in pairs]).reshape(-1, 3)
            if not (spans_plane(cur) and spans_plane(ref)):
                continue
            cc, rc = cur.mean(axis=0), ref.mean(axis=0)
            rot = Rotation.align_vectors(ref - rc, cur - cc)[0].as_matrix()
            carry = lambda p: None if p is None else rot @ (p - cc) + rc
            registered.append(([carry(p) for p in lip], [carry(p) for p in fh]))
        if not registered:
            registered = raw
            break
        reference = mean_forehead(registered)
    d0_cam = np.array([robust_mean([f[0][i] for f in registered if f[0][i] is not None])
                       for i in range(n)])
    return d0_cam, {j: r for j, r in enumerate(reference) if r is not None}


def dot_index(name):
    m = re.fullmatch(r"([DF])([1-9][0-9]*)", name)
    return m.group(1), int(m.group(2)) - 1


# ---------------------------------------------------------------- deformation (§5)

def deformation(mode, d0, p0, driver, width, manual):
    if mode == "manual":
        return manual
    eps = 0.02 * width
    e_perf = d0.max(axis=0) - d0.min(axis=0)
    e_char = p0.max(axis=0) - p0.min(axis=0)
    f = np.where((e_perf < eps) | (e_char == 0), e_char[0] / e_perf[0], e_char / np.where(e_perf == 0, 1, e_perf))
    m = np.tile(f, (len(p0), 1))
    if mode == "per-axis":
        return m
    for n in range(len(p0)):
        d = d0[driver[n]]
        for k in range(3):
            if abs(d[k]) >= eps and p0[n, k] != 0 and np.sign(p0[n, k]) == np.sign(d[k]):
                m[n, k] = min(max(p0[n, k] / d[k], 0.05), 20.0)
    return m


# ---------------------------------------------------------------- smoothing (§8)

def smooth(points, method, radius=1, alpha=0.5, samples=8):
    n = len(points)
    if method == "none":
        return None
    if method == "sg5":
        return savgol_filter(points, 5, 2, axis=0, mode="wrap")
    if method == "bspline":
        # Periodic cubic B-spline with the points as control points on integer knots: span i
        # (parameter i..i+1) is governed by control points i-1..i+2.
        coeffs = np.vstack([points[-1:], points, points[:2]])  # P[-1], P[0..n-1], P[n], P[n+1]
        knots = np.arange(-3, n + 4, dtype=float)  # t_j = j - 3
        spline = BSpline(knots, coeffs, 3)
        u = np.arange(n * samples) / samples
        return spline(u)
    offsets = np.arange(-radius, radius + 1)
    if method == "ma":
        w = np.ones(len(offsets))
    elif method == "ma-weighted":
        w = (radius + 1 - np.abs(offsets)).astype(float)
    elif method == "ma-exp":
        w = alpha ** np.abs(offsets)
    w = w / w.sum()
    return sum(wj * np.roll(points, -j, axis=0) for j, wj in zip(offsets, w))


# ---------------------------------------------------------------- retarget (§4, §6)

def run(character, lines, smooth_method="bspline", hold=0.5, decay=0.5, samples=8, radius=1,
        alpha=0.5):
    ch = character
    n = len(ch["names"])
    flagged = [l for l in lines if l.get("neutral")]
    neutral = flagged if flagged else lines[:1]
    n_fh = max([dot_index(k)[1] + 1 for l in neutral for k in l["points"] if k[0] == "F"] + [0])
    d0_cam, fh_ref = neutral_pose(neutral, n, n_fh)
    up = np.mean(list(fh_ref.values()), axis=0) - (d0_cam[0] + d0_cam[n // 2]) / 2
    origin, axes, width = mouth_frame(d0_cam[0], d0_cam[n // 2], up)
    d0 = (d0_cam - origin) @ axes
    m = deformation(ch["mode"], d0, ch["p0"], ch["driver"], width, ch["manual"])

    rig = rig_reference.Rig(d0)
    rot, trans = np.eye(3), np.zeros(3)  # last good alignment current -> neutral
    last = [None] * n
    out = []
    for seq, l in enumerate(lines):
        t = l["t"]
        cur, ref = [], []
        for k, v in l["points"].items():
            kind, i = dot_index(k)
            if kind == "F" and v is not None and i in fh_ref:
                cur.append(v)
                ref.append(fh_ref[i])
        head_lost = True
        if len(cur) >= 3:
            cur, ref = np.array(cur), np.array(ref)
            cc, rc = cur.mean(axis=0), ref.mean(axis=0)
            if np.linalg.matrix_rank(cur - cc, tol=1e-9) >= 2:
                r, _ = Rotation.align_vectors(ref - rc, cur - cc)
                rot = r.as_matrix()
                trans = rc - rot @ cc
                head_lost = False
        d = np.zeros((n, 3))
        conf = np.zeros(n)
        for i in range(n):
            v = l["points"].get(f"D{i + 1}")
            if v is not None:
                d[i] = (rot @ np.array(v) + trans - origin) @ axes
                conf[i] = 1.0
                last[i] = (d[i].copy(), t)
            elif last[i] is None:
                d[i] = d0[i]
            else:
                value, seen = last[i]
                age = t - seen
                if age <= hold:
                    d[i] = value
                elif decay > 0 and age < hold + decay:
                    d[i] = value + (d0[i] - value) * (age - hold) / decay
                else:
                    d[i] = d0[i]
        p = ch["p0"] + (d[ch["driver"]] - d0[ch["driver"]]) * m
        head_rot = rot.T
        head_t = -rot.T @ trans
        q = Rotation.from_matrix(head_rot).as_quat()  # x, y, z, w
        q = np.array([q[3], q[0], q[1], q[2]])
        if q[0] < 0:
            q = -q
        curve = smooth(p, smooth_method, radius=radius, alpha=alpha, samples=samples)
        out.append({
            "t": t, "seq": seq, "character": ch["name"],
            "points": {nm: p[j].tolist() for j, nm in enumerate(ch["names"])},
            "confidence": {nm: float(conf[ch["driver"][j]]) for j, nm in enumerate(ch["names"])},
            "head": {"rotation": q.tolist(), "translation": head_t.tolist()},
            "head_lost": head_lost,
            # The camera's centre (the camera frame's origin) in the neutral mouth frame.
            "rig": rig.step(t, d, conf > 0, (trans - origin) @ axes),
            "curve": None if curve is None else
            {"method": smooth_method, "closed": True, "points": np.asarray(curve).tolist()},
        })
    return out, m


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--character", required=True)
    ap.add_argument("--input", required=True)
    ap.add_argument("--out", default="-")
    ap.add_argument("--smooth", default="bspline")
    ap.add_argument("--samples-per-span", type=int, default=8)
    ap.add_argument("--ma-radius", type=int, default=1)
    ap.add_argument("--ma-alpha", type=float, default=0.5)
    ap.add_argument("--hold", type=float, default=0.5)
    ap.add_argument("--decay", type=float, default=0.5)
    a = ap.parse_args()
    character = load_character(a.character)
    with open(a.input) as f:
        lines = [json.loads(s) for s in f if s.strip()]
    out, _ = run(character, lines, a.smooth, a.hold, a.decay, a.samples_per_span, a.ma_radius,
                 a.ma_alpha)
    dst = sys.stdout if a.out == "-" else open(a.out, "w")
    for o in out:
        dst.write(json.dumps(o) + "\n")


if __name__ == "__main__":
    main()
