#!/usr/bin/env python3
"""Independent reference of mouthpiece's rig (docs/rig.md), in numpy/scipy.

Follows docs/rig.md, which defines every number computed here: the jaw (angle and slide
about the hinge), each lip's rigid motion (scipy's `Rotation.align_vectors`, not the Rust SVD)
and the 27 ARKit-named curves and the five VRM visemes with their default ranges widened over the learning window, and
the dots as the rig measures them (the Gaussian conditional mean of the mouth's displacement
given the seen dots and their noise along and across the camera's ray, under the covariance of
the complete steps, computed here with numpy's `cov` over all of them and a solve on the seen
block, where the Rust keeps running sums and pads one fixed-size system).
Its own code throughout (numpy arrays, not the Rust loops); where the page was not precise
enough to write it, the page was completed.
`retarget_reference.py` calls `Rig.step` with the stabilised dots of every line (which were
seen, and where the camera is in the mouth frame), and the
`retarget_cli` tests compare the binary's `rig` with it.

Everything is in the performer's neutral mouth frame (x to the performer's left, y up, z out
of the mouth; metres), relative to the neutral dots `d0`. Dot roles: the left corner is dot 0,
the right corner dot n/2, the upper lip the dots between them, the lower lip the rest.
"""

import numpy as np
from scipy.spatial.transform import Rotation

CURVE_NAMES = [
    "jawOpen", "mouthClose", "mouthFunnel", "mouthPucker", "mouthLeft", "mouthRight",
    "mouthSmileLeft", "mouthSmileRight", "mouthStretchLeft", "mouthStretchRight",
    "mouthRollUpper", "mouthRollLower", "mouthUpperUpLeft", "mouthUpperUpRight",
    "mouthLowerDownLeft", "mouthLowerDownRight", "mouthPressLeft", "mouthPressRight",
    "jawForward", "jawLeft", "jawRight", "mouthFrownLeft", "mouthFrownRight",
    "mouthShrugUpper", "mouthShrugLower", "mouthDimpleLeft", "mouthDimpleRight",
]
VISEME_NAMES = ["aa", "ih", "ou", "ee", "oh"]

# docs/rig.md, "The named curves": default ranges (degrees for jawOpen, mouth widths else).
DEFAULT_RANGES = {
    "jawOpen": 25.0, "mouthClose": 25.0, "mouthFunnel": 0.15, "mouthPucker": 0.15,
    "mouthLeft": 0.10, "mouthRight": 0.10, "mouthSmileLeft": 0.12, "mouthSmileRight": 0.12,
    "mouthStretchLeft": 0.15, "mouthStretchRight": 0.15, "mouthRollUpper": 0.10,
    "mouthRollLower": 0.16, "mouthUpperUpLeft": 0.10, "mouthUpperUpRight": 0.10,
    "mouthLowerDownLeft": 0.12, "mouthLowerDownRight": 0.12, "mouthPressLeft": 0.15,
    "mouthPressRight": 0.15, "jawForward": 0.20, "jawLeft": 0.18, "jawRight": 0.18,
    "mouthFrownLeft": 0.11, "mouthFrownRight": 0.11, "mouthShrugUpper": 0.14,
    "mouthShrugLower": 0.16, "mouthDimpleLeft": 0.30, "mouthDimpleRight": 0.30,
}

# docs/rig.md: the lips' opening (mouth widths) at which the rounding is all funnel; where
# the visemes' `ih` peaks.
OPEN_WIDTHS = 0.1
SLIGHT_OPEN = 0.3


def visemes(c):
    """docs/rig.md, "Visemes": the five VRM 1.0 mouth expressions from the curves `c`."""
    o = np.clip(c["jawOpen"] - c["mouthClose"], 0, 1)
    rho = np.clip(c["mouthFunnel"] + c["mouthPucker"], 0, 1)
    sigma = (c["mouthStretchLeft"] + c["mouthStretchRight"]) / 2
    slight = np.clip(min(o / SLIGHT_OPEN, (1 - o) / (1 - SLIGHT_OPEN)), 0, 1)
    v = [o * (1 - rho), sigma * (1 - rho) * slight, rho * (1 - o), sigma * (1 - rho) * (1 - o), rho * o]
    return {k: float(x) for k, x in zip(VISEME_NAMES, v)}

DEPTH_WEIGHT = 0.25

# docs/rig.md, "The dots the rig measures".
FILL_LEARN_STEPS = 20
RAY_NOISE_M = 0.0012
ACROSS_NOISE_M = 0.0003
PRIOR_WIDTH = 2.0
SHAPE_GATE = 3.0
DISOWN_M = 0.006
DISOWN_WITNESSES = 3


def rotate_x(v, angle):
    """(y, z) turned by `angle` about the x axis (y towards z for a positive angle)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([v[0] * c - v[1] * s, v[0] * s + v[1] * c])


def lip_motion(a, b):
    """The rigid motion carrying the dots `a` onto `b` (least squares), as the wire has it."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    r, _ = Rotation.align_vectors(b - cb, a - ca)
    m = r.as_matrix()
    t = cb - m @ ca
    residual = np.sqrt(np.mean(np.sum((a @ m.T + t - b) ** 2, axis=1)))
    x, y, z, w = r.as_quat()
    q = np.array([w, x, y, z])
    if q[0] < 0:
        q = -q
    return {"rotation": q.tolist(), "translation": t.tolist(), "residual": float(residual)}


class Rig:
    def __init__(self, d0, hinge_up=0.5, hinge_back=1.6, learn_s=4.0, ranges=None):
        self.d0 = np.asarray(d0, float)
        n = len(self.d0)
        self.left, self.right = 0, n // 2
        self.upper = list(range(1, n // 2))
        self.lower = list(range(n // 2 + 1, n))
        self.w = np.linalg.norm(self.d0[self.left] - self.d0[self.right])
        # The pivot: hinge_up widths above the mouth centre, hinge_back behind it (y, z).
        self.pivot = np.array([hinge_up * self.w, -hinge_back * self.w])
        self.learn_s = learn_s
        self.set = dict(ranges or {})
        self.ranges = {k: self.set.get(k, v) for k, v in DEFAULT_RANGES.items()}
        # mouthClose's range is jawOpen's unless it is set.
        if "mouthClose" not in self.set:
            self.ranges["mouthClose"] = self.ranges["jawOpen"]
        self.start = None
        # Every complete step's displacement from neutral (3 per dot), for the fill.
        self.complete = []
        # The dots the last step measured, and the stabilised dots it was given.
        self.measured = None
        self.given = None

    def estimate(self, d, seen, camera):
        """`d` as the rig measures it: the mouth's expected displacement given the seen dots,
        each with its noise along and across its ray to `camera` (mouth frame), under the
        complete steps' mean and covariance (numpy's `cov` of all of them, widened by
        PRIOR_WIDTH): the unseen dots (those a seen dot of their lip or a corner can say
        something of) always, the seen ones unless the step is farther than SHAPE_GATE from
        what was learned, and a seen one the others disown (DISOWN_M) like an unseen one."""
        seen = np.asarray(seen, bool)
        x = (d - self.d0).reshape(-1)
        if seen.all():
            self.complete.append(x)
        if len(self.complete) < FILL_LEARN_STEPS or not seen.any():
            return d
        data = np.array(self.complete)
        mean, cov = data.mean(axis=0), PRIOR_WIDTH * np.cov(data, rowvar=False)
        # A lip with none of its dots seen (the corners count for both lips) stays held.
        corner = seen[self.left] or seen[self.right]
        upper, lower = corner or seen[self.upper].any(), corner or seen[self.lower].any()
        moved = ~seen
        moved[self.upper] &= upper
        moved[self.lower] &= lower
        rays = camera - d
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        noise = np.zeros((len(x), len(x)))
        for k, r in enumerate(rays):
            noise[3 * k:3 * k + 3, 3 * k:3 * k + 3] = (
                ACROSS_NOISE_M ** 2 * np.eye(3) + (RAY_NOISE_M ** 2 - ACROSS_NOISE_M ** 2) * np.outer(r, r))

        def solve(used):
            s = np.repeat(used, 3)
            residual = x[s] - mean[s]
            weights = np.linalg.solve(cov[np.ix_(s, s)] + noise[np.ix_(s, s)], residual)
            share = np.zeros(len(x))
            share[s] = residual * weights
            return mean + cov[:, s] @ weights, residual @ weights / s.sum(), share.reshape(-1, 3).sum(1)

        expected, distance, share = solve(seen)
        kept = seen
        disowned = np.zeros(len(seen), bool)
        # A dot the others disown is not measured: beyond the gate, the seen dot with the
        # largest share of the distance, when the others (at least DISOWN_WITNESSES) then lie
        # within it and put that dot farther than DISOWN_M from where it was read.
        if distance > SHAPE_GATE and seen.sum() > DISOWN_WITNESSES:
            k = int(np.argmax(np.where(seen, share, -np.inf)))
            others = seen.copy()
            others[k] = False
            e2, d2, _ = solve(others)
            if d2 <= SHAPE_GATE and np.linalg.norm(e2[3 * k:3 * k + 3] - x[3 * k:3 * k + 3]) > DISOWN_M:
                expected, distance, kept = e2, d2, others
                disowned[k] = True
        u = np.repeat(moved | disowned | (kept & (distance <= SHAPE_GATE)), 3)
        x = x.copy()
        x[u] = expected[u]
        return self.d0 + x.reshape(-1, 3)

    def side_weight(self, i):
        """The weight of dot i for the performer's left side (right: 1 − it)."""
        return float(np.clip(0.5 + self.d0[i, 0] / (self.w / 2), 0.0, 1.0))

    def measures(self, d):
        d0, w, up, lo = self.d0, self.w, self.upper, self.lower
        delta = d - d0
        du = delta[up].mean(axis=0)
        dl = delta[lo].mean(axis=0)
        c0 = d0[lo].mean(axis=0)
        # Jaw angle: the lower-lip centroid turned about the pivot in the (y, z) plane, after
        # the upper lip's forward motion (shared by both lips) is taken off its motion.
        r0 = c0[1:] - self.pivot
        r1 = r0 + np.array([dl[1], dl[2] - du[2]])
        angle = np.arctan2(r0[0] * r1[1] - r0[1] * r1[0], r0 @ r1)
        slide = dl[0] - du[0]

        def without_jaw(i):
            """Dot i's motion with the jaw's rotation and slide undone."""
            p = d[i].copy()
            p[0] -= slide
            p[1:] = self.pivot + rotate_x(p[1:] - self.pivot, -angle)
            return p - d0[i]

        free = {i: without_jaw(i) for i in lo + [self.left, self.right]}
        m = {}
        m["jawOpen"] = np.degrees(angle)
        jaw_drop = c0[1] - (self.pivot + rotate_x(r0, angle))[0]
        gap = du[1] - dl[1]
        # The part of the jaw's opening the lips do not show as parting, in degrees.
        m["mouthClose"] = (
            np.degrees(angle) * np.clip((jaw_drop - max(gap, 0)) / jaw_drop, 0, 1)
            if angle > 0 and jaw_drop > 0 else 0.0)
        # Horizontal scale: least squares x ≈ s·x0 over every dot (the lower lip's x without
        # the slide); each side's scale about the centre moved by the midline-weighted shift.
        x = d[:, 0].copy()
        x[lo] -= slide
        x0 = d0[:, 0]
        s = (x @ x0) / (x0 @ x0)
        mid = np.clip(1 - np.abs(x0) / (w / 2), 0, 1)
        centre = (mid @ (x - x0)) / mid.sum() if mid.sum() > 0 else 0.0
        xc = x - centre
        left, right = x0 >= 0, x0 < 0
        s_left = (xc[left] @ x0[left]) / (x0[left] @ x0[left])
        s_right = (xc[right] @ x0[right]) / (x0[right] @ x0[right])
        rounding = DEPTH_WEIGHT * du[2] / w + max(1 - s, 0) / 2
        opened = float(np.clip(gap / w / OPEN_WIDTHS, 0, 1))
        m["mouthFunnel"] = rounding * opened
        m["mouthPucker"] = rounding * (1 - opened)
        shift = (d[:, 0] - x0).mean() / w
        m["mouthLeft"], m["mouthRight"] = shift, -shift

        def corner(c, upper_n, lower_n):
            cy = 0.5 * (delta[c, 1] + free[c][1])
            return (cy + delta[upper_n, 1] + free[lower_n][1]) / 3 / w

        m["mouthSmileLeft"] = corner(self.left, up[0], lo[-1])
        m["mouthSmileRight"] = corner(self.right, up[-1], lo[0])
        m["mouthStretchLeft"] = (s_left - 1) / 2
        m["mouthStretchRight"] = (s_right - 1) / 2
        m["mouthRollUpper"] = np.mean([-delta[i, 1] - DEPTH_WEIGHT * delta[i, 2] for i in up]) / w
        m["mouthRollLower"] = np.mean([free[i][1] - DEPTH_WEIGHT * free[i][2] for i in lo]) / w

        def sided(idx, values):
            wl = np.array([self.side_weight(i) for i in idx])
            v = np.array(values)
            return (wl @ v) / wl.sum(), ((1 - wl) @ v) / (1 - wl).sum()

        up_l, up_r = sided(up, [delta[i, 1] for i in up])
        lo_l, lo_r = sided(lo, [free[i][1] for i in lo])
        m["mouthUpperUpLeft"], m["mouthUpperUpRight"] = up_l / w, up_r / w
        m["mouthLowerDownLeft"], m["mouthLowerDownRight"] = -lo_l / w, -lo_r / w
        m["mouthPressLeft"], m["mouthPressRight"] = (lo_l - up_l) / w, (lo_r - up_r) / w
        m["jawForward"] = (np.linalg.norm(r1) - np.linalg.norm(r0)) / w
        m["jawLeft"], m["jawRight"] = slide / w, -slide / w
        m["mouthFrownLeft"] = -m["mouthSmileLeft"]
        m["mouthFrownRight"] = -m["mouthSmileRight"]
        m["mouthShrugUpper"] = np.mean([delta[i, 1] + DEPTH_WEIGHT * delta[i, 2] for i in up]) / w
        m["mouthShrugLower"] = (dl[1] + DEPTH_WEIGHT * (dl[2] - du[2])) / w

        def back(c, upper_n, lower_n):
            cz = 0.5 * (delta[c, 2] + free[c][2])
            return (du[2] - (cz + delta[upper_n, 2] + free[lower_n][2]) / 3) / w

        m["mouthDimpleLeft"] = back(self.left, up[0], lo[-1])
        m["mouthDimpleRight"] = back(self.right, up[-1], lo[0])
        return m, angle, slide

    def step(self, t, d, seen=None, camera=(0.0, 0.0, 0.6)):
        given = np.asarray(d, float)
        seen = np.ones(len(given), bool) if seen is None else np.asarray(seen, bool)
        d = given.copy()
        if self.given is not None:
            # A dot the stabiliser holds (unseen, unchanged since the last step) stays where
            # the rig last measured it.
            held = ~seen & np.all(given == self.given, axis=1)
            d[held] = self.measured[held]
        self.given = given
        d = self.estimate(d, seen, np.asarray(camera, float))
        self.measured = d
        m, angle, slide = self.measures(d)
        if self.start is None:
            self.start = t
        if t - self.start <= self.learn_s:
            for k, v in m.items():
                if k not in self.set and np.isfinite(v):
                    self.ranges[k] = max(self.ranges[k], v)
            if "mouthClose" not in self.set:
                self.ranges["mouthClose"] = self.ranges["jawOpen"]
        curves = {}
        for k in CURVE_NAMES:
            v = m[k] / self.ranges[k]
            curves[k] = float(np.clip(v, 0, 1)) if np.isfinite(v) else 0.0
        lips = {}
        for name, idx in (("upper", self.upper), ("lower", self.lower)):
            idx = idx + [self.left, self.right]
            lips[name] = lip_motion(self.d0[idx], d[idx])
        return {
            "jaw": {"angle_deg": float(np.degrees(angle)), "slide_m": float(slide)},
            "lips": lips,
            "curves": curves,
            "visemes": visemes(curves),
        }
