#!/usr/bin/env python3
"""Recomputes the rig's accuracy from `mouthpiece evaluate --rig-frames FILE` and splits the
tracked curves' error by its source.

    mouthpiece evaluate --seeds 2 --head-motion strong --rig-frames rig.csv --per-curve
    python3 scripts/rig-error-split.py rig.csv

Per session it prints:

- `recomputed`: the largest difference between the curves in the file and those the
  independent numpy reference (`tests/reference/rig_reference.py`, written from docs/rig.md)
  computes from the same stabilised dots, neutral dots and ranges (both the tracked and the
  true side): the file's curves are what the definitions give;
- `worst curve` and `funnel r`, `jawOpen r`: recomputed from the rows, the figures of
  `evaluate`'s rig table (numpy's `corrcoef`, not the Rust accumulator); "funnel r" is the
  rounding's, `mouthFunnel + mouthPucker` (the two split it by the lips' opening), as in
  `evaluate`;
- `funnel r, common error off`: the funnel's correlation with the synthetic rounding after the
  part of the tracked dots' error that every lip dot shares (the mean of tracked − true over
  the dots, per frame: mostly the head pose's error, which moves every dot alike) is taken off
  the tracked dots; what a perfect head pose would leave;
- `funnel r, depth error off`: with every tracked dot's depth replaced by the true one;
- `worst curve, unseen dots true`: the worst curve's RMS (over all curves) once every dot the
  tracker did not see that frame (`seen_D*` 0; the rig measured it where the seen ones put
  it) is moved by its true displacement from neutral instead: what a perfect fill would give.
"""

import csv
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests", "reference"))
import rig_reference  # noqa: E402

NAMES = rig_reference.CURVE_NAMES


def curves(rig, ranges, dots):
    """The 18 curves of `dots` with the frame's `ranges` (as the file gives them: learned up to
    that frame, or set)."""
    m, _, _ = rig.measures(dots)
    return np.array([np.clip(m[k] / ranges[i], 0, 1) if np.isfinite(m[k] / ranges[i]) else 0.0
                     for i, k in enumerate(NAMES)])


def session_report(rows):
    n_dots = sum(1 for k in rows[0] if k.startswith("tracked_D") and k.endswith("_x"))
    dots = [f"D{i + 1}" for i in range(n_dots)]

    def block(row, side):
        return np.array([[float(row[f"{side}_{d}_{a}"]) for a in "xyz"] for d in dots])

    ranges = np.array([[float(r[f"range_{k}"]) for k in NAMES] for r in rows])
    tracked_rig = rig_reference.Rig(block(rows[0], "tracked_neutral"))
    true_rig = rig_reference.Rig(block(rows[0], "reference_neutral"))
    tracked_file = np.array([[float(r[f"tracked_{k}"]) for k in NAMES] for r in rows])
    true_file = np.array([[float(r[f"reference_{k}"]) for k in NAMES] for r in rows])
    tracked_dots = np.array([block(r, "tracked") for r in rows])
    true_dots = np.array([block(r, "reference") for r in rows])
    tracked = np.array([curves(tracked_rig, g, d) for g, d in zip(ranges, tracked_dots)])
    true = np.array([curves(true_rig, g, d) for g, d in zip(ranges, true_dots)])
    recomputed = max(np.abs(tracked - tracked_file).max(), np.abs(true - true_file).max())

    rnd = np.array([float(r["true_round"]) for r in rows])
    jaw = np.array([float(r["true_jaw_deg"]) for r in rows])
    rms = np.sqrt(((tracked - true) ** 2).mean(axis=0))
    worst = int(np.argmax(rms))
    funnel, pucker = NAMES.index("mouthFunnel"), NAMES.index("mouthPucker")
    jaw_open = NAMES.index("jawOpen")

    def r(x, y):
        return np.corrcoef(x, y)[0, 1]

    def rounding(c):
        """The rounding, which mouthFunnel and mouthPucker split by the lips' opening."""
        return c[:, funnel] + c[:, pucker]

    common = (tracked_dots - true_dots).mean(axis=1, keepdims=True)
    without_common = np.array([curves(tracked_rig, g, d)
                               for g, d in zip(ranges, tracked_dots - common)])
    seen = np.array([[r.get(f"seen_{d}", "1") == "1" for d in dots] for r in rows])
    true_neutral, tracked_neutral = block(rows[0], "reference_neutral"), block(rows[0], "tracked_neutral")
    perfect_fill = np.where(seen[:, :, None], tracked_dots,
                            tracked_neutral + true_dots - true_neutral)
    with_perfect_fill = np.array([curves(tracked_rig, g, d) for g, d in zip(ranges, perfect_fill)])
    true_depth = tracked_dots.copy()
    true_depth[:, :, 2] = true_dots[:, :, 2]
    without_depth_error = np.array([curves(tracked_rig, g, d) for g, d in zip(ranges, true_depth)])
    return {
        "frames": len(rows),
        "recomputed": recomputed,
        "worst": (NAMES[worst], rms[worst]),
        "jawOpen r": r(tracked[:, jaw_open], jaw),
        "funnel r": r(rounding(tracked), rnd),
        "funnel r, true dots": r(rounding(true), rnd),
        "funnel r, common error off": r(rounding(without_common), rnd),
        "funnel r, depth error off": r(rounding(without_depth_error), rnd),
        "common error RMS (mm, x y z)": 1e3 * np.sqrt((common[:, 0, :] ** 2).mean(axis=0)),
        "worst, unseen dots true": np.sqrt(((with_perfect_fill - true) ** 2).mean(axis=0)).max(),
        "unseen": int((~seen).sum()),
    }


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    with open(sys.argv[1], newline="") as f:
        rows = list(csv.DictReader(f))
    sessions = {}
    for row in rows:
        sessions.setdefault((row["seed"], row["noise"], row["head_motion"]), []).append(row)
    print("| seed | noise | head motion | frames | recomputed | worst curve | its RMS | jawOpen r "
          "| funnel r | on the true dots | common error off | depth error off "
          "| common error RMS x, y, z (mm) | unseen dots | worst curve, unseen dots true |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for (seed, noise, motion), rs in sessions.items():
        s = session_report(rs)
        c = s["common error RMS (mm, x y z)"]
        print(f"| {seed} | {noise} | {motion} | {s['frames']} | {s['recomputed']:.1e} "
              f"| {s['worst'][0]} | {s['worst'][1]:.3f} | {s['jawOpen r']:.3f} "
              f"| {s['funnel r']:.3f} | {s['funnel r, true dots']:.3f} "
              f"| {s['funnel r, common error off']:.3f} | {s['funnel r, depth error off']:.3f} "
              f"| {c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f} | {s['unseen']} "
              f"| {s['worst, unseen dots true']:.3f} |")


if __name__ == "__main__":
    main()
