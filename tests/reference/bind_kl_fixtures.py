#!/usr/bin/env python3
"""Reference KL divergences for mouthpiece's binding evaluation, computed with scipy.

Writes tests/reference/bind_kl_fixtures.json, read by crates/bind/tests/integration/kl.rs: pairs of skin
weight rows (13 joints: the 12 mouth points and the root) with `scipy.stats.entropy(p, q)`,
the KL divergence KL(p || q) in nats after normalising both rows. Some p rows are sparse (at
most four influences, as a bound vertex has), some unnormalised.

    python3 tests/reference/bind_kl_fixtures.py
"""

import json
import os

import numpy as np
import scipy
from scipy.stats import entropy


def main():
    rng = np.random.default_rng(20)
    cases = []
    for i in range(24):
        p = rng.random(13)
        if i % 3 == 0:
            p[np.argsort(p)[:9]] = 0.0  # four influences
        if i % 4 != 1:
            p /= p.sum()
        q = rng.random(13) + 1e-3
        q /= q.sum()
        cases.append({"p": p.tolist(), "q": q.tolist(), "kl": float(entropy(p, q))})
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "bind_kl_fixtures.json")
    with open(out, "w") as f:
        json.dump({"scipy": scipy.__version__, "cases": cases}, f, indent=1)
        f.write("\n")


if __name__ == "__main__":
    main()
