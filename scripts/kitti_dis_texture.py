"""Would ``--dis-min-texture`` help on KITTI as it does on TUM fr3/teddy? DIS's error by texture.

On KITTI 06 (its stereo depth, as ``deepslam train --source`` computes it, and its ground-truth motion:
06 is the slice whose single frames the shipped model trained on, never the scored 07), for every 5th
consecutive pair: DIS medium's end-point error against the flow synthesized from the depth and the
motion, on the real pair and on the view rendered from frame i with that motion (6 grey levels of
noise, as ``train --appearance-noise 6``), by quartile of frame i's texture
(:func:`flow.images.texture_strength`), on pixels with a stereo depth under 80 m. About 1 minute:

    .venv/bin/python scripts/kitti_dis_texture.py [KITTI_06_DIR]
"""
from __future__ import annotations

import sys

import numpy as np


def main(argv: list[str]) -> int:
    from deepslam.core.readers import open_sequence
    from deepslam.flow import estimators as fe, registry
    from deepslam.gen.flow import synthesize
    from deepslam.gen.novel_view import render_novel_view
    from deepslam.vo.data.frames import depth_source, _frame_depth

    seq = open_sequence(argv[0] if argv else "../shared/data/kitti/sequences/06")
    how = depth_source(seq, "auto")
    dis = registry.make("dis", preset="medium")
    real, synthetic, texture = [], [], []
    for i in range(0, len(seq) - 1, 5):
        depth = _frame_depth(seq, i, how, False, seq.camera.width, seq.camera.height).astype(np.float32)
        motion = np.linalg.inv(seq.gt_pose(i + 1)) @ seq.gt_pose(i)  # cam_{i+1}_from_cam_i
        ref, valid = synthesize(depth, seq.camera, motion)
        ref, valid = ref.numpy(), valid.numpy() & np.isfinite(depth) & (depth > 0) & (depth < 80)
        g0, g1 = fe.to_grey(seq.image(i)), fe.to_grey(seq.image(i + 1))
        view, _ = render_novel_view(g0, depth, seq.camera, motion)
        noisy = np.clip(np.rint(view + np.random.default_rng(i).normal(0, 6, view.shape)), 0, 255).astype(np.uint8)
        real.append(np.linalg.norm(dis.estimate(g0, g1) - ref, axis=2)[valid])
        synthetic.append(np.linalg.norm(dis.estimate(g0, noisy) - ref, axis=2)[valid])
        texture.append(fe.texture_strength(g0)[valid])
    real, synthetic, texture = map(np.concatenate, (real, synthetic, texture))
    print(f"{len(real)} pixels; texture >= 0.5 (what --dis-min-texture 0.5 keeps): {100 * (texture >= 0.5).mean():.0f} %")
    edges = np.quantile(texture, [0.0, 0.25, 0.5, 0.75, 1.0])
    for k, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
        sel = (texture >= lo) & (texture <= hi)
        print(f"texture quartile {k + 1} ({lo:.3g}-{hi:.3g}): DIS median error, real pair {np.median(real[sel]):.2f} px, "
              f"synthetic view {np.median(synthetic[sel]):.2f} px")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
