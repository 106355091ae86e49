#!/usr/bin/env python3
"""Writes a copy of a rig.yaml (OpenCV FileStorage, as `eyesim synth` writes it) with one camera perturbed:
rotated about its own x axis (the camera centre stays), moved along its own x axis, or its focal lengths scaled.

  perturb_rig.py IN OUT --camera 0 --rotate-deg 0.05
  perturb_rig.py IN OUT --camera 0 --move-um 100
  perturb_rig.py IN OUT --camera 0 --focal-scale 1.001
"""
import argparse
import math
import re
import sys


def matrix(block, key):
    m = re.search(r"(\n\s+" + key + r": !!opencv-matrix.*?data: \[)(.*?)(\])", block, re.S)
    if not m:
        sys.exit(f"perturb_rig.py: {key}: not found")
    return m, [float(x) for x in m.group(2).replace("\n", " ").split(",")]


def put(block, m, values):
    return block[: m.start(2)] + " " + ", ".join(repr(v) for v in values) + " " + block[m.end(2):]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("inp")
    ap.add_argument("out")
    ap.add_argument("--camera", type=int, default=0)
    ap.add_argument("--rotate-deg", type=float, default=0.0)
    ap.add_argument("--move-um", type=float, default=0.0)
    ap.add_argument("--focal-scale", type=float, default=1.0)
    a = ap.parse_args()
    text = open(a.inp).read()
    m = re.search(r"\ncam%d:\n(.*?)(?=\ncam\d+:\n|\Z)" % a.camera, text, re.S)
    if not m:
        sys.exit(f"perturb_rig.py: {a.inp}: no cam{a.camera}")
    block = m.group(0)
    # Rotation about the camera's own x axis, centre fixed: R' = Rx R, t' = Rx t.
    th = math.radians(a.rotate_deg)
    c, s = math.cos(th), math.sin(th)
    rx = [[1, 0, 0], [0, c, -s], [0, s, c]]
    mr, r = matrix(block, "R")
    R = [r[0:3], r[3:6], r[6:9]]
    R2 = [[sum(rx[i][k] * R[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    block = put(block, mr, [R2[i][j] for i in range(3) for j in range(3)])
    mt, t = matrix(block, "t")
    t2 = [sum(rx[i][k] * t[k] for k in range(3)) for i in range(3)]
    # Moved along its own x axis by d: the centre C' = C + d·x_cam, so t' = t − d·e_x.
    t2[0] -= a.move_um * 1e-3
    block = put(block, mt, t2)
    mk, k = matrix(block, "K")
    k[0] *= a.focal_scale
    k[4] *= a.focal_scale
    block = put(block, mk, k)
    open(a.out, "w").write(text[: m.start()] + block + text[m.end():])


if __name__ == "__main__":
    main()
