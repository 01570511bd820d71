#!/usr/bin/env python3
"""Writes one unseen random test case for `mouthpiece retarget` into a folder:

- `character.toml`: a random non-human character (random size and units, given in a randomly
  rotated and shifted model frame with a sloppy `up`, sometimes from contours, sometimes with a
  `[map]`, any `m_mode`);
- `input.jsonl`: a random performer (performer.py) with a moving head, noise, dropouts;
- `case.json`: the CLI options chosen and the reference's own figures (mouth width).
- `expected.jsonl`: the reference implementation's output (retarget_reference.py).

    python3 random_case.py --seed 3 --dir /tmp/case3
"""

import argparse
import json
import os

import numpy as np

import performer
import retarget_reference


def random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def fmt(v):
    return "[" + ", ".join(repr(float(c)) for c in v) + "]"


def character_toml(rng, seed):
    width = 10 ** rng.uniform(-1, 1.5)  # 0.1 .. 30 units
    half = width / 2
    height = width * rng.uniform(0.1, 0.8)
    depth = width * rng.uniform(0.05, 2.5)  # up to a long muzzle
    # Mouth-frame outline: left corner, upper lip left→right, right corner, lower right→left.
    ang = np.linspace(0, np.pi, 7)
    upper = np.column_stack([half * np.cos(ang), 0.5 * height * np.sin(ang) ** rng.uniform(0.5, 2),
                             depth * np.sin(ang) ** 2])
    lower = np.column_stack([-half * np.cos(ang), -0.5 * height * np.sin(ang) ** rng.uniform(0.5, 2),
                             depth * rng.uniform(0.6, 1.0) * np.sin(ang) ** 2])
    mouth = np.vstack([upper, lower[1:6]])
    mouth[1:6] += rng.normal(0, 0.05 * width, (5, 3)) * [1, 0.3, 0.3]
    mouth[7:12] += rng.normal(0, 0.05 * width, (5, 3)) * [1, 0.3, 0.3]
    if rng.random() < 0.3:
        mouth[3, 1] *= -0.2  # an "upper" point below the corner line: opposite signs
    r = random_rotation(rng)
    offset = rng.normal(0, 3 * width, 3)
    model = mouth @ r.T + offset
    up = r @ (np.array([0.0, 1.0, 0.0]) + rng.uniform(-0.5, 0.5) * np.array([1.0, 0, 0])) * rng.uniform(0.5, 3)
    lines = [f'name = "creature-{seed}"', f"up = {fmt(up)}"]
    names = [f"P{i + 1}" for i in range(12)]
    use_contour = rng.random() < 0.25
    mode = rng.choice(["per-point", "per-point", "per-axis", "manual"])
    if mode != "per-point" or rng.random() < 0.5:
        lines.append(f'm_mode = "{mode}"')
    if use_contour:
        up_poly = np.vstack([model[0], model[1:6], model[6]])
        low_poly = np.vstack([model[0], model[7:12][::-1], model[6]])
        lines += ["", "[contour]", "points_per_lip = 7",
                  "upper = [" + ", ".join(fmt(p) for p in up_poly) + "]",
                  "lower = [" + ", ".join(fmt(p) for p in low_poly) + "]"]
    else:
        order = list(range(12))
        if rng.random() < 0.5:
            order = list(rng.permutation(12))  # file order differs from P1..P12
            order.remove(0)
            order.insert(0, 0)
        lines += ["", "[points]"] + [f"{names[i]} = {fmt(model[i])}" for i in order]
    if rng.random() < 0.4:
        # Swap which dots drive two lip points (corners stay put).
        driver = list(range(12))
        a, b = rng.choice([1, 2, 3, 4, 5, 7, 8, 9, 10, 11], 2, replace=False)
        driver[a], driver[b] = driver[b], driver[a]
        lines += ["", "[map]"] + [f'D{driver[i] + 1} = "{names[i]}"' for i in range(12)]
    if mode == "manual":
        lines += ["", "[m]"] + [f"{names[i]} = {fmt(rng.uniform(0.3, 5, 3))}" for i in range(12)]
    return "\n".join(lines) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--dir", required=True)
    a = ap.parse_args()
    rng = np.random.default_rng([20261122, a.seed])
    os.makedirs(a.dir, exist_ok=True)
    char_path = os.path.join(a.dir, "character.toml")
    with open(char_path, "w") as f:
        f.write(character_toml(rng, a.seed))
    head = rng.choice(["moderate", "strong"])
    lines = performer.generate(int(rng.integers(1 << 30)), seconds=rng.uniform(2.0, 4.0),
                               fps=float(rng.choice([30.0, 60.0])), head=head,
                               noise=float(rng.uniform(0, 0.0008)),
                               dropout=float(rng.uniform(0, 0.08)), decimals=None,
                               flag_neutral=bool(rng.random() < 0.85))
    # Blackouts: a few steps in which no lip dot is seen at all (the tracker named none), and
    # a few in which the lower lip and both corners are not (a lip rolled in).
    body = [i for i, line in enumerate(lines) if not line.get("neutral")]
    n = sum(1 for k in lines[0]["points"] if k.startswith("D"))
    for lost in (range(n), [0] + list(range(n // 2, n))):
        start = int(rng.choice(body[len(body) // 3:-6]))
        for i in range(start, start + int(rng.integers(2, 6))):
            for k in lost:
                lines[i]["points"][f"D{k + 1}"] = None
    # Misreads: a few steps in which one seen lip dot is read 12 mm deeper (a fast lip's
    # blurred trail over the open mouth).
    for i in rng.choice(body[len(body) // 3:], size=3, replace=False):
        k = f"D{int(rng.integers(n)) + 1}"
        if lines[i]["points"][k] is not None:
            lines[i]["points"][k] = [v + dv for v, dv in zip(lines[i]["points"][k], (0.0, 0.0, 0.012))]
    with open(os.path.join(a.dir, "input.jsonl"), "w") as f:
        for line in lines:
            f.write(json.dumps(line) + "\n")
    smooth = str(rng.choice(["none", "ma", "ma-weighted", "ma-exp", "sg5", "bspline"]))
    options = {
        "smooth": smooth,
        "samples_per_span": int(rng.integers(1, 12)),
        "ma_radius": int(rng.integers(1, 4)),
        "ma_alpha": float(rng.uniform(0.2, 1.0)),
        "hold": float(rng.uniform(0, 0.3)),
        "decay": float(rng.uniform(0, 0.3)),
    }
    character = retarget_reference.load_character(char_path)
    out, m = retarget_reference.run(character, lines, smooth, options["hold"], options["decay"],
                                    options["samples_per_span"], options["ma_radius"],
                                    options["ma_alpha"])
    with open(os.path.join(a.dir, "expected.jsonl"), "w") as f:
        for o in out:
            f.write(json.dumps(o) + "\n")
    case = dict(options, mouth_width=float(character["width"]), head=str(head), m=m.tolist())
    with open(os.path.join(a.dir, "case.json"), "w") as f:
        json.dump(case, f, indent=1)


if __name__ == "__main__":
    main()
