#!/usr/bin/env python3
"""The bind family evaluation: the three skinning methods on meshes the generator did not
make (docs/bind.md, "Meshes from outside the generator").

    python3 bench/bind_families.py [--dir DIR] [--large] [--keep]

1. `family_eval bases DIR` writes three held-out generator heads as OBJ;
2. Blender (headless, bench/blender/bind_families.py) decimates them and models three heads
   of its own;
3. `family_eval eval DIR` builds the subdivided, shell and seam families, scores every mesh
   and prints the Markdown table (per mesh on stderr).

Nothing generated is kept unless --keep (the meshes go to a temporary folder by default).
--large adds one head subdivided to about 200 000 vertices (heat diffusion then takes minutes).
"""

import argparse
import os
import shutil
import subprocess
import sys
import tempfile

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dir", help="folder for the meshes (default: a temporary one)")
    ap.add_argument("--large", action="store_true")
    ap.add_argument("--keep", action="store_true")
    args = ap.parse_args()
    work = args.dir or tempfile.mkdtemp(prefix="bind-families-")
    os.makedirs(work, exist_ok=True)
    example = ["cargo", "run", "-q", "-p", "mouthpiece-bind", "--example", "family_eval", "--"]
    try:
        subprocess.run(example + ["bases", work], cwd=REPO, check=True)
        subprocess.run(
            [
                "blender", "-b", "--factory-startup", "--python-exit-code", "1", "--python",
                os.path.join(REPO, "bench", "blender", "bind_families.py"), "--", work,
            ],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        subprocess.run(
            example + ["eval", work] + (["--large"] if args.large else []), cwd=REPO, check=True
        )
    finally:
        if not (args.keep or args.dir):
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
