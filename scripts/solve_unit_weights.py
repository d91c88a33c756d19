"""The solve pose head with every weight 1: an untrained model file whose pose is the plain Gauss-Newton
least-squares fit of the flow with the frame's depth (:mod:`vo.geometry.posesolve`; the weight network's last
layer starts at 0). A classical dense flow + depth baseline that runs through the same `deepslam vo`
path as the learned models; the network shape and the DIS record (``meta.flow``) are copied from
REFERENCE, so it reads the same flow at the same resolution:

    .venv/bin/python scripts/solve_unit_weights.py REFERENCE.safetensors OUT.safetensors
"""
from __future__ import annotations

import argparse
import sys


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("reference")
    p.add_argument("out")
    args = p.parse_args(argv)

    from deepslam.vo.geometry.posesolve import unit_weight_net
    from deepslam.vo.modelfiles.modelio import load_model, save_model

    ref, meta = load_model(args.reference)
    out_meta = {"untrained": "solve head, every weight 1"}
    if meta.get("flow"):
        out_meta["flow"] = meta["flow"]
    save_model(args.out, unit_weight_net(ref.cfg), out_meta)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
