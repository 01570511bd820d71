#!/usr/bin/env python3
"""Independent numpy implementation of lip sync's mapping and stitching (docs/lipsync.md).

Reads a JSON list of cases on stdin, writes a JSON list of results on stdout. A case:
  {"fps": 60, "t_change": 0.04, "silence": 0,
   "phones": [[start, end, class], ...],            # touching, in time order
   "segments": {"a,b": {"stable": [[[u, w], ...] per pose], "change": [...]}}}
A result: {"values": [[w per pose] per sample], "owner": [phone index per sample]}.

Written from the method's description, not from the Rust code: stage curves are monotone
cubic Hermite (PCHIP) with slope 0 at both ends and Fritsch-Butland interior slopes; phone i
on [t1, t2] takes segment (class_i, class_{i+1} or silence): change stage on [t2 - T, t2],
stable stage scaled onto [t1, t2 - T]; shorter phones start their change stage at
max(t2 - T, first phone's start) with no stable stage; stitching blends overlaps with r rising
linearly from the new curve's start to the old curve's end.
"""

import json
import sys

import numpy as np


def pchip_flat(points, u):
    """Monotone cubic Hermite through points (u_k, w_k), zero slope at the ends, at u."""
    p = np.asarray(points, dtype=float)
    x, y = p[:, 0], p[:, 1]
    h = np.diff(x)
    d = np.diff(y) / h
    m = np.zeros_like(y)
    if len(x) > 2:
        h0, h1 = h[:-1], h[1:]
        d0, d1 = d[:-1], d[1:]
        w1 = 2 * h1 + h0
        w2 = h1 + 2 * h0
        same = d0 * d1 > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            mid = (w1 + w2) / (w1 / d0 + w2 / d1)
        m[1:-1] = np.where(same, mid, 0.0)
    u = np.clip(np.asarray(u, dtype=float), 0.0, 1.0)
    k = np.clip(np.searchsorted(x, u, side="right") - 1, 0, len(x) - 2)
    hk = x[k + 1] - x[k]
    s = (u - x[k]) / hk
    return (
        (2 * s**3 - 3 * s**2 + 1) * y[k]
        + (s**3 - 2 * s**2 + s) * hk * m[k]
        + (-2 * s**3 + 3 * s**2) * y[k + 1]
        + (s**3 - s**2) * hk * m[k + 1]
    )


def run_case(case):
    fps, T, silence = case["fps"], case["t_change"], case["silence"]
    phones = case["phones"]
    segs = case["segments"]
    k = len(next(iter(segs.values()))["stable"])
    end = max(p[1] for p in phones)
    n = int(np.floor(end * fps)) + 1
    while n > 1 and (n - 1) / fps > end:
        n -= 1
    while n / fps <= end:
        n += 1
    t = np.arange(n) / fps
    values = np.zeros((n, k))
    owner = np.zeros(n, dtype=int)
    origin = phones[0][0]
    c_end = -np.inf
    for i, (t1, t2, a) in enumerate(phones):
        b = phones[i + 1][2] if i + 1 < len(phones) else silence
        seg = segs[f"{a},{b}"]
        cs = t2 - T
        start = t1 if t2 - t1 >= T else max(cs, origin)
        sel = (t >= start) & (t <= t2)
        ts = t[sel]
        here = np.zeros((len(ts), k))
        stable = (ts < cs) & (cs > t1)
        for p in range(k):
            if cs > t1:
                us = (ts - t1) / (cs - t1)
                here[:, p] = np.where(
                    stable, pchip_flat(seg["stable"][p], us), pchip_flat(seg["change"][p], (ts - cs) / T)
                )
            else:
                here[:, p] = pchip_flat(seg["change"][p], (ts - cs) / T)
        old = values[sel]
        blend = ts < c_end
        r = np.where(blend, (ts - start) / np.where(blend, c_end - start, 1.0), 1.0)
        values[sel] = np.where(blend[:, None], (1 - r)[:, None] * old + r[:, None] * here, here)
        o = owner[sel]
        owner[sel] = np.where(~blend | (r >= 0.5), i, o)
        c_end = max(c_end, t2)
    return {"values": values.tolist(), "owner": owner.tolist()}


def main():
    cases = json.load(sys.stdin)
    json.dump([run_case(c) for c in cases], sys.stdout)


if __name__ == "__main__":
    main()
