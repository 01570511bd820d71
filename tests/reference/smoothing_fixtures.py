#!/usr/bin/env python3
"""Reference values for mouthpiece's shape smoothing (docs/method.md §8), computed with scipy.

Writes tests/reference/smoothing_fixtures.json, read by crates/retarget/tests/integration/smoothing.rs:
- Savitzky-Golay 5-point quadratic on a closed loop: scipy.signal.savgol_filter(window 5,
  order 2, mode="wrap");
- closed uniform cubic B-spline with the points as control points: scipy.interpolate.BSpline
  on integer knots with the control points wrapped, sampled `samples` times per span.

    python3 tests/reference/smoothing_fixtures.py
"""

import json
import os

import numpy as np
import scipy
from scipy.interpolate import BSpline
from scipy.signal import savgol_filter


def closed_bspline(points, samples):
    n = len(points)
    coeffs = np.vstack([points[-1:], points, points[:2]])
    knots = np.arange(-3, n + 4, dtype=float)  # t_j = j - 3: span i is [i, i+1)
    return BSpline(knots, coeffs, 3)(np.arange(n * samples) / samples)


def main():
    rng = np.random.default_rng(8)
    cases = []
    for n, samples in [(12, 8), (5, 3), (16, 1), (9, 5)]:
        ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
        pts = np.column_stack([np.cos(ang), 0.4 * np.sin(ang), 0.1 * np.sin(3 * ang)])
        pts += rng.normal(0, 0.05, pts.shape)
        cases.append({
            "points": pts.tolist(),
            "sg5": savgol_filter(pts, 5, 2, axis=0, mode="wrap").tolist(),
            "samples_per_span": samples,
            "bspline": closed_bspline(pts, samples).tolist(),
        })
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "smoothing_fixtures.json")
    with open(out, "w") as f:
        json.dump({"generator": f"scipy {scipy.__version__}", "cases": cases}, f)
        f.write("\n")


if __name__ == "__main__":
    main()
