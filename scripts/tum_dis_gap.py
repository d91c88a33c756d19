"""How far DIS's flow on TUM fr3/teddy's real pairs is from the training's synthetic views.

For every 4th consecutive pair of the slice (45 pairs), the reference flow is synthesized from frame i's
sensor depth and the motion a classical RGB-D odometry finds (the ``pnp`` plug-in: SIFT + PnP-RANSAC
with the sensor depth; no ground-truth pose is used). Printed: the median end-point error of DIS
(medium) against it on the real pair (i, i + 1), and on the synthetic second view rendered from frame i
and the same motion (what ``train --synthetic-flow dis`` makes), with 0-24 grey levels of Gaussian
noise on that view (``--appearance-noise``); and of the learned flow (``models/flow_learned.safetensors``)
on the real pair and the noise-free view. Then, over all these pixels pooled, DIS's error on the real
pairs by quartile of the first image's texture (:func:`flow.images.texture_strength`) and what
each ``--dis-min-texture`` threshold keeps (how 0.5 was chosen: no pose and no odometry score is
used). Pixels with sensor depth only. About 2 minutes:

    .venv/bin/python scripts/tum_dis_gap.py [TEDDY_DIR]
"""
from __future__ import annotations

import sys

import numpy as np


def main(argv: list[str]) -> int:
    from deepslam.core import se3
    from deepslam.core.readers import open_sequence
    from deepslam.gen.flow import synthesize
    from deepslam.gen.novel_view import render_novel_view
    from deepslam.slam.classical import make_pnp
    from deepslam.flow import estimators as flow_estimators, images as flow_images, registry as flow_registry

    root = argv[0] if argv else "../shared/data/tum/rgbd_dataset_freiburg3_teddy"
    seq = open_sequence(root)
    dis = flow_registry.make("dis", preset="medium")
    learned = flow_registry.make("learned")
    pairs = [(i, i + 1) for i in range(0, len(seq) - 1, 4)][:45]
    vec, _ = make_pnp().predict(seq, pairs)
    noises = (0, 6, 12, 18, 24)
    errors: dict[str, list[float]] = {}
    pixel_errors, pixel_texture = [], []
    for (i, j), v in zip(pairs, vec):
        depth = np.asarray(seq.depth(i), np.float32)
        motion = se3.from_euler6(v[None])[0]
        ref, valid = synthesize(depth, seq.camera, motion)
        ref, valid = ref.numpy(), valid.numpy() & (depth > 0)
        grey0 = flow_images.to_grey(seq.image(i))

        def epe(flow: np.ndarray) -> float:
            return float(np.median(np.linalg.norm(flow[valid] - ref[valid], axis=1)))

        grey1 = flow_images.to_grey(seq.image(j))
        real = dis.estimate(grey0, grey1)
        errors.setdefault("real pair", []).append(epe(real))
        pixel_errors.append(np.linalg.norm(real[valid] - ref[valid], axis=1))
        pixel_texture.append(flow_images.texture_strength(grey0)[valid])
        errors.setdefault("real pair, learned flow", []).append(epe(learned.estimate(grey0, grey1)))
        view, _ = render_novel_view(grey0, depth, seq.camera, motion)
        errors.setdefault("synthetic view, learned flow", []).append(epe(learned.estimate(grey0, view)))
        for sigma in noises:
            noisy = view if sigma == 0 else np.clip(
                np.rint(view + np.random.default_rng(i).normal(0.0, sigma, view.shape)), 0, 255).astype(np.uint8)
            errors.setdefault(f"synthetic view, noise {sigma}", []).append(epe(dis.estimate(grey0, noisy)))
    for name, e in errors.items():
        who = "" if "learned" in name else "DIS "
        print(f"{name:28s} {who}end-point error, median over {len(e)} pairs: {np.median(e):.2f} px")
    err, tex = np.concatenate(pixel_errors), np.concatenate(pixel_texture)
    edges = np.quantile(tex, [0.0, 0.25, 0.5, 0.75, 1.0])
    for k, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
        sel = (tex >= lo) & (tex <= hi)
        print(f"real pairs, texture quartile {k + 1} ({lo:.3g}-{hi:.3g} (grey levels/px)^2): DIS median error "
              f"{np.median(err[sel]):.2f} px")
    for t in (0.25, 0.5, 1.0, 2.0):
        sel = tex >= t
        print(f"--dis-min-texture {t:g} keeps {100 * sel.mean():.0f} % of the pixels; their DIS median error "
              f"{np.median(err[sel]):.2f} px, mean {err[sel].mean():.2f} px (all: {np.median(err):.2f} / {err.mean():.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
