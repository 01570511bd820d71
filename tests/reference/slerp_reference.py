"""Independent reference for the head turn's quaternion interpolation: scipy's Slerp.

Reads JSON on stdin: {"pairs": [[q0, q1], ...], "s": [s0, s1, ...]} with quaternions as
[w, x, y, z]; prints JSON {"results": [[q(s0), q(s1), ...], ...]} with each interpolated
rotation as [w, x, y, z] (w >= 0). scipy's Slerp interpolates the relative rotation's rotation
vector (the shortest way), which is what the head's turn must do.

    python slerp_reference.py < pairs.json
"""

import json
import sys

import numpy as np
from scipy.spatial.transform import Rotation, Slerp


def wxyz_to_xyzw(q):
    w, x, y, z = q
    return [x, y, z, w]


def main():
    data = json.load(sys.stdin)
    s = np.array(data["s"], dtype=np.float64)
    results = []
    for q0, q1 in data["pairs"]:
        rotations = Rotation.from_quat([wxyz_to_xyzw(q0), wxyz_to_xyzw(q1)])
        out = Slerp([0.0, 1.0], rotations)(s).as_quat()
        out = [[q[3], q[0], q[1], q[2]] for q in out]
        out = [q if q[0] >= 0 else [-c for c in q] for q in out]
        results.append(out)
    json.dump({"results": results}, sys.stdout)


if __name__ == "__main__":
    sys.exit(main())
