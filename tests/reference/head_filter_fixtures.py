#!/usr/bin/env python3
"""Reference values for the tracker's head filter (docs/detection.md, step 9), computed with
filterpy's Kalman filter (an independent implementation of the textbook equations).

A head turning about one fixed axis, its forehead middle moving, both measured with noise.
About one fixed axis the filter on the rotation's tangent space is the linear filter on the
angle: each of the three axes sees the same innovations scaled by the axis's component, with
the same gains. So the reference filters the angle and each coordinate of the middle with a
constant-velocity KalmanFilter (state: position, speed; the white-noise acceleration model,
Q = q [[dt³/3, dt²/2], [dt²/2, dt]]; first state: the first measurement at rest, covariance
diag(σ², 1)).

Writes tests/reference/head_filter_fixtures.json, read by
crates/track/src/head_filter.rs (`agrees_with_filterpy`).

    pip install filterpy numpy
    python3 tests/reference/head_filter_fixtures.py
"""

import json
import os

import filterpy
import numpy as np
from filterpy.kalman import KalmanFilter

ROTATION_SIGMA = np.radians(0.2)
SHIFT_SIGMA = 2e-4


def cv_filter(z, t, sigma, q):
    """The filtered positions of the series `z` measured at times `t`."""
    kf = KalmanFilter(dim_x=2, dim_z=1)
    kf.H = np.array([[1.0, 0.0]])
    kf.R = np.array([[sigma * sigma]])
    kf.x = np.array([[z[0]], [0.0]])
    kf.P = np.diag([sigma * sigma, 1.0])
    out = [z[0]]
    for k in range(1, len(z)):
        dt = t[k] - t[k - 1]
        kf.F = np.array([[1.0, dt], [0.0, 1.0]])
        kf.Q = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
        kf.predict()
        kf.update(np.array([[z[k]]]))
        out.append(float(kf.x[0, 0]))
    return out


def main():
    rng = np.random.default_rng(18)
    cases = []
    for n, (rotation_accel, shift_accel) in [(90, (0.05, 0.003)), (60, (0.5, 0.05))]:
        # Uneven frame times (a camera's jitter), 30 fps on average.
        t = np.cumsum(np.concatenate([[0.0], rng.uniform(0.028, 0.039, n - 1)]))
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = 0.3 * np.sin(2.0 * t) + 0.2 * t + rng.normal(0, ROTATION_SIGMA, n)
        middle = (np.column_stack([0.02 * np.sin(3.0 * t), 0.01 * t, 0.6 + 0.005 * np.cos(t)])
                  + rng.normal(0, SHIFT_SIGMA, (n, 3)))
        cases.append({
            "rotation_accel": rotation_accel,
            "shift_accel": shift_accel,
            "t": t.tolist(),
            "axis": axis.tolist(),
            "angle": angle.tolist(),
            "middle": middle.tolist(),
            "filtered_angle": cv_filter(angle, t, ROTATION_SIGMA, rotation_accel),
            "filtered_middle": np.column_stack(
                [cv_filter(middle[:, i], t, SHIFT_SIGMA, shift_accel) for i in range(3)]
            ).tolist(),
        })
    out = {"filterpy": filterpy.__version__, "rotation_sigma_rad": ROTATION_SIGMA,
           "shift_sigma_m": SHIFT_SIGMA, "cases": cases}
    path = os.path.join(os.path.dirname(__file__), "head_filter_fixtures.json")
    with open(path, "w") as f:
        json.dump(out, f)
        f.write("\n")


if __name__ == "__main__":
    main()
