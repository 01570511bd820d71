#!/usr/bin/env python3
"""Every rig session of `mouthpiece evaluate` outputs against the rig's targets.

Usage: rig-misses.py DIR_OR_FILE...

Reads the rig table rows (markdown, as `evaluate` prints them) of every `*.txt` in each
directory (or each file given) and prints every session that misses a target: jaw RMS
<= 1.5 deg, slide RMS <= 1 mm, the worst curve's RMS <= 0.05, `jawOpen` r >= 0.95 and
`mouthFunnel` r >= 0.95 (with, when the table has them, the funnel's r on the true dots and
the rounding's standard deviation). Then the totals, and how the funnel's misses lie against
the rounding's standard deviation (a performer who hardly rounds leaves the correlation to
the noise: docs/rig.md, "Accuracy").
"""
import glob
import os
import sys

TARGETS = "jaw <= 1.5 deg, slide <= 1 mm, worst curve <= 0.05, jawOpen r >= 0.95, mouthFunnel r >= 0.95"


def rows(path):
    for line in open(path, encoding="utf-8"):
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) in (10, 12) and cells[0].isdigit():
            yield cells


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    paths = []
    for arg in sys.argv[1:]:
        paths += sorted(glob.glob(os.path.join(arg, "*.txt"))) if os.path.isdir(arg) else [arg]
    sessions = misses = funnel_misses = 0
    by_sd = []  # (round SD, funnel r, funnel r on the true dots) of every session that has them
    for path in paths:
        for c in rows(path):
            sessions += 1
            jaw, slide, worst, jr, fr = float(c[4]), float(c[5]), float(c[7]), float(c[8]), float(c[9])
            bad = []
            if jaw > 1.5:
                bad.append(f"jaw {jaw:.2f} deg")
            if slide > 1.0:
                bad.append(f"slide {slide:.2f} mm")
            if worst > 0.05:
                bad.append(f"{c[6]} {worst:.3f}")
            if jr < 0.95:
                bad.append(f"jawOpen r {jr:.3f}")
            if not fr >= 0.95:
                funnel_misses += 1
                extra = f" (true dots {c[10]}, round SD {c[11]})" if len(c) == 12 else ""
                bad.append(f"mouthFunnel r {fr:.3f}{extra}")
            if len(c) == 12:
                by_sd.append((float(c[11]), fr, float(c[10])))
            if bad:
                misses += 1
                print(f"{os.path.basename(path)}: seed {c[0]} {c[1]} {c[2]}, {c[3]} frames: " + "; ".join(bad))
    print(f"{sessions} sessions, {sessions - misses} meet every target ({TARGETS}), {misses} miss; "
          f"the funnel's r misses on {funnel_misses}")
    if by_sd:
        missed = [sd for sd, r, _ in by_sd if not r >= 0.95]
        if missed:
            top = max(missed)
            low = [x for x in by_sd if x[0] <= top]
            print(f"the funnel's r misses on {len(missed)} of the {len(low)} sessions whose rounding SD is at most "
                  f"{top:.3f} (on the true dots: {sum(1 for _, _, t in low if not t >= 0.95)}), "
                  f"on none of the {len(by_sd) - len(low)} above it")
        else:
            print(f"the funnel's r meets 0.95 on all {len(by_sd)} sessions "
                  f"(rounding SD {min(by_sd)[0]:.3f} to {max(by_sd)[0]:.3f})")

if __name__ == "__main__":
    main()
