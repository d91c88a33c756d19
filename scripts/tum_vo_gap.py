"""Where a VO model's error on TUM fr3/teddy comes from: the network, or the real flow.

For every 2nd consecutive pair of the slice, the motion the classical ``pnp`` plug-in finds (SIFT +
PnP-RANSAC with the sensor depth; no ground-truth pose is used) is the reference. Each model reads
three flows of the pair: the exact flow synthesized from frame i's sensor depth and that motion, DIS
on the view rendered from frame i with that motion (what ``train --synthetic-flow dis`` trains on),
and DIS on the real pair. DIS is set up as the model was trained (:func:`vo.modelfiles.models.flow_for_model`),
and where that leaves textureless pixels out the exact flow leaves out the same pixels. Printed per
model and flow: the median ratio of the translation read to the reference's, and the median
translation (cm) and rotation (deg) errors. The exact row is the network's own error; the step to
the synthetic DIS row is DIS's, as trained; the step to the real row is the real pairs' gap.
About 1 minute a model:

    .venv/bin/python scripts/tum_vo_gap.py MODEL.safetensors [MODEL ...] [--sequence TEDDY_DIR] [--dis-fb-check PX]
"""
from __future__ import annotations

import argparse
import sys

import numpy as np


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("models", nargs="+")
    p.add_argument("--sequence", default="../shared/data/tum/rgbd_dataset_freiburg3_teddy")
    p.add_argument("--dis-fb-check", type=float, default=None, metavar="PX",
                   help="DIS's forward-backward check for every model (default: each model's own, as trained)")
    args = p.parse_args(argv)

    from deepslam.core import se3
    from deepslam.core.readers import open_sequence
    from deepslam.flow import estimators as fe
    from deepslam.gen.flow import synthesize
    from deepslam.gen.novel_view import render_novel_view
    from deepslam.slam.classical import make_pnp
    from deepslam.vo.data.frames import frame_inverse_depth
    from deepslam.vo.infer import VOPredictor
    from deepslam.vo.modelfiles import models

    seq = open_sequence(args.sequence)
    pairs = [(i, i + 1) for i in range(0, len(seq) - 1, 2)]
    ref6, _ = make_pnp().predict(seq, pairs)
    for path in args.models:
        pred = VOPredictor.from_file(path)
        dis = models.flow_for_model("dis", path, fb_max_px=args.dis_fb_check)
        min_texture = getattr(dis, "min_texture", 0.0)
        h, w = pred.input_size
        reads: dict[str, list[np.ndarray]] = {}
        for (i, j), v in zip(pairs, ref6):
            depth = np.asarray(seq.depth(i), np.float32)
            motion = se3.from_euler6(v[None])[0]
            exact, valid = synthesize(depth, seq.camera, motion)
            g0, g1 = fe.to_grey(seq.image(i)), fe.to_grey(seq.image(j))
            keep = valid.numpy() & (depth > 0) & (fe.texture_strength(g0) >= min_texture)
            exact = np.where(keep[..., None], exact.numpy(), np.nan)
            view, _ = render_novel_view(g0, depth, seq.camera, motion)
            inv = frame_inverse_depth(seq, i, w, h)[None] if pred.needs_depth else None
            for name, flow in (("exact", exact), ("DIS, synthetic view", dis.estimate(g0, view)),
                               ("DIS, real pair", dis.estimate(g0, g1))):
                x, k = pred.prepare(flow, seq.camera)
                reads.setdefault(name, []).append(pred.predict(x[None], k[None], inv)[0][0])
        print(f"{path} (flow {dis.name})")
        ref = np.asarray(ref6)
        for name, r in reads.items():
            m = np.asarray(r)
            ratio = np.linalg.norm(m[:, 3:], axis=1) / np.linalg.norm(ref[:, 3:], axis=1)
            t_err = np.linalg.norm(m[:, 3:] - ref[:, 3:], axis=1)
            r_err = np.degrees(np.linalg.norm(m[:, :3] - ref[:, :3], axis=1))
            print(f"  {name:20s} translation read / reference {np.median(ratio):.2f}, error {100 * np.median(t_err):.2f} cm, "
                  f"rotation error {np.median(r_err):.3f} deg (median over {len(m)} pairs; reference translation "
                  f"{100 * np.median(np.linalg.norm(ref[:, 3:], axis=1)):.2f} cm)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
