#!/usr/bin/env python3
"""Compares two `mouthpiece evaluate` tables (markdown, as printed) row by row.

Usage: compare-accuracy-tables.py BEFORE AFTER

Rows are matched by (seed, noise, head motion). A row passes when found & named is within
0.05 percentage points, every millimetre, degree and character figure within 0.05, the
frame, calibration and visible-dot figures equal, and there are no more wrong names than
before. Prints one line per row and exits 1 if any row fails or is missing.
"""
import sys


def rows(path):
    out = {}
    for line in open(path, encoding="utf-8"):
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 13 or not cells[0].isdigit():
            continue
        out[tuple(cells[:3])] = cells[3:]
    return out


def main():
    before, after = rows(sys.argv[1]), rows(sys.argv[2])
    bad = 0
    for key, old in before.items():
        new = after.get(key)
        if new is None:
            print("missing", key)
            bad += 1
            continue
        frames, calib, visible, found, wrong, hidden, mm, deg, cv, ca = range(10)
        problems = []
        for i in (frames, calib, visible):
            if old[i] != new[i]:
                problems.append(f"{old[i]} -> {new[i]}")
        pct = lambda s: float(s.rstrip("%").strip())
        if abs(pct(old[found]) - pct(new[found])) > 0.05 + 1e-9:
            problems.append(f"found {old[found]} -> {new[found]}")
        if int(new[wrong]) > int(old[wrong]):
            problems.append(f"wrong {old[wrong]} -> {new[wrong]}")
        for i in (mm, deg, cv, ca):
            if abs(float(old[i]) - float(new[i])) > 0.05 + 1e-9:
                problems.append(f"{old[i]} -> {new[i]}")
        same = old == new
        status = "equal" if same else ("within tolerance" if not problems else "DIFFERS")
        print(" ".join(key), status, "; ".join(problems) if problems else "",
              "" if same else f"(hidden {old[hidden]} -> {new[hidden]})")
        bad += bool(problems)
    print(f"{len(before)} rows, {bad} outside the tolerance")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
