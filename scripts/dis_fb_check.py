"""How DIS's forward-backward check (``--dis-fb-check``) and texture threshold act on renders with exact flow.

For every 10th consecutive pair of a rendered sequence (default: the simulated room the TUM models train
on), DIS (medium) runs with each texture threshold and each check; printed: the share of pixels kept,
the share of the occluded pixels kept (the simulator's occlusion masks: the surface seen in frame t is
not visible in t + 1), and the end-point error against the simulator's exact flow over the kept visible
pixels (mean, median, share > 1 px). How the TUM recipe's 0.5 px was chosen (no real data used). About
a minute a sequence:

    .venv/bin/python scripts/dis_fb_check.py [RENDER_DIR ...]
"""
from __future__ import annotations

import sys

import numpy as np


def main(argv: list[str]) -> int:
    from deepslam.core.readers import open_sequence
    from deepslam.flow import estimators as fe

    for root in argv or ["out/tum_models/room_k2"]:
        seq = open_sequence(root)
        if seq.flow_paths is None or seq.occlusion_paths is None:
            print(f"{root}: no exact flow and occlusion masks (render with flow)", file=sys.stderr)
            return 2
        pairs = range(0, len(seq) - 1, 10)
        print(f"{root} ({len(pairs)} pairs)")
        for fb in (0.0, 0.5, 1.0, 2.0):
            for tex in (0.0, 0.5):
                dis = fe.DISFlow("medium", tex, fb)
                errors, kept, occluded_kept = [], [], []
                for i in pairs:
                    flow, exact, occluded = dis.estimate(seq.image(i), seq.image(i + 1)), seq.flow(i), seq.occlusion(i)
                    known = np.isfinite(flow[..., 0])
                    errors.append(np.linalg.norm(flow - exact, axis=-1)[known & ~occluded])
                    kept.append(known.mean())
                    if occluded.any():
                        occluded_kept.append(known[occluded].mean())
                e = np.concatenate(errors)
                print(f"  {dis.name:22s} kept {np.mean(kept):.3f}, occluded kept {np.mean(occluded_kept):.3f}, "
                      f"EPE of the kept visible pixels: mean {e.mean():.3f} px, median {np.median(e):.3f}, "
                      f"> 1 px {100 * np.mean(e > 1):.1f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
