#!/usr/bin/env python3
"""Replays variants of the funnel's measure on `mouthpiece evaluate --rig-frames` files and
measures the upper lip's depth error (docs/rig.md, "Accuracy": the funnel's misses).

    mouthpiece evaluate --seeds 121,122,...,140 --character config/characters/human.toml \\
        --rig-frames rig.csv
    python3 scripts/funnel-variants.py rig.csv [more.csv ...]

Per session with a rounding SD of at most 0.11, and as a mean, minimum and count below 0.95
over every session: the Pearson r of each variant with the synthetic rounding, on the tracked
(`t…`) and on the true (`r…`) dots:

- `cur`: the definition, ¼ · (mean Δz of the upper lip) / w + max(1 − s, 0) / 2, with `s` the
  least-squares horizontal scale of every lip dot (here without the jaw's slide, which the
  synthetic jaw does not have);
- `avg2`, `avg3`: the depth term averaged over this frame and the last one or two (causal);
- `c0.5`, `c1.0`: the corners' depth push, scaled by 4/3 (the synthetic rounding moves them
  ¾ as far as the lips' middle), averaged in with the upper lip's at half or full weight.

Then per session: the mean depth error of the upper lip (tracked − true, mm): its SD, its
lag-1 autocorrelation (how much of it one frame shares with the next) and its correlation with
the lower lip's and the corners' (how much of it every lip dot shares, as the head pose's
error would be).
"""

import collections
import csv
import sys

import numpy as np

DOTS = 12
HALF = DOTS // 2
UPPER = list(range(1, HALF))
LOWER = list(range(HALF + 1, DOTS))
CORNERS = [0, HALF]
NAMES = [f"D{i + 1}" for i in range(DOTS)]


def block(row, side):
    return np.array([[float(row[f"{side}_{d}_{a}"]) for a in "xyz"] for d in NAMES])


def variants(rows, side):
    n0 = block(rows[0], side + "_neutral")
    w = np.linalg.norm(n0[0] - n0[HALF])
    p = np.array([block(r, side) for r in rows])
    d = p - n0
    s = (p[:, :, 0] * n0[:, 0]).sum(1) / (n0[:, 0] ** 2).sum()
    inward = 0.5 * np.maximum(0, 1 - s)
    upper_z = d[:, UPPER, 2].mean(1) / w
    corner_z = d[:, CORNERS, 2].mean(1) / w
    out = {"cur": 0.25 * upper_z + inward}
    for frames in (2, 3):
        # Causal: the first frames average what there is.
        kept = np.array([upper_z[max(0, i - frames + 1):i + 1].mean() for i in range(len(upper_z))])
        out[f"avg{frames}"] = 0.25 * kept + inward
    for weight in (0.5, 1.0):
        mixed = (len(UPPER) * upper_z + weight * len(CORNERS) * corner_z / 0.75) / (
            len(UPPER) + weight * len(CORNERS))
        out[f"c{weight}"] = 0.25 * mixed + inward
    return out


def lag1(x):
    x = x - x.mean()
    return float((x[1:] * x[:-1]).sum() / (x * x).sum())


def main(paths):
    totals = collections.defaultdict(list)
    for path in paths:
        sessions = collections.defaultdict(list)
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                sessions[(row["seed"], row["noise"], row["head_motion"])].append(row)
        for key, rows in sessions.items():
            rounding = np.array([float(r["true_round"]) for r in rows])
            rs = {}
            for side, tag in (("tracked", "t"), ("reference", "r")):
                for name, x in variants(rows, side).items():
                    rs[tag + name] = float(np.corrcoef(x, rounding)[0, 1])
            for k, v in rs.items():
                totals[k].append(v)
            err = np.array([block(r, "tracked") - block(r, "reference") for r in rows]) * 1e3
            up, low, cor = (err[:, ix, 2].mean(1) for ix in (UPPER, LOWER, CORNERS))
            print(" ".join(key), f"round SD {rounding.std():.3f}",
                  f"upper-lip depth error SD {up.std():.2f} mm, lag-1 {lag1(up):.2f},",
                  f"r with lower lip {np.corrcoef(up, low)[0, 1]:.2f},",
                  f"with corners {np.corrcoef(up, cor)[0, 1]:.2f}")
            if rounding.std() <= 0.11:
                print("   ", " ".join(f"{k}={v:.3f}" for k, v in sorted(rs.items())))
    print("over", len(totals["tcur"]), "sessions:")
    for k, v in sorted(totals.items()):
        v = np.array(v)
        print(f"  {k}: mean {v.mean():.4f}, min {v.min():.3f}, below 0.95: {(v < 0.95).sum()}")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
