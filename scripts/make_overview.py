"""docs/img/overview.png: one rendered street frame with movers and what the simulator knows about it
(depth, exact flow to the next frame, instance masks), beside the flow synthesized from that single frame's
depth and a sampled motion (the paper's training data).

    python scripts/make_overview.py            # renders into out/overview (about 20 s), writes the PNG
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import cv2
import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

from deepslam.cli import main as deepslam_main  # noqa: E402
from deepslam.core import se3  # noqa: E402
from deepslam.core.colorize import flow_to_rgb  # noqa: E402
from deepslam.core.plots import new_figure, save_figure  # noqa: E402
from deepslam.core.readers import open_sequence  # noqa: E402
from deepslam.gen.flow import synthesize  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def main() -> int:
    seq_dir = REPO / "out" / "overview"
    if not (seq_dir / "poses.txt").is_file():
        rc = deepslam_main(["render", "--scene", "street", "--frames", "12", "--width", "640", "--moving-objects", "6",
                            "--grainy-road", "--seed", "7", "--out", str(seq_dir), "--quiet"]
                           + (["--resume"] if seq_dir.exists() else []))
        if rc:
            return rc
    seq = open_sequence(seq_dir)
    k = int(np.argmax([(seq.mask(i) > 0).mean() for i in range(len(seq) - 1)]))  # the frame with most traffic
    depth = seq.depth(k)
    motion = se3.from_euler6(np.array([0.0, 0.03, 0.0, 0.0, 0.0, 1.2]))  # a turn while driving 1.2 m
    synth, _ = synthesize(depth, seq.camera, motion)
    synth = np.asarray(synth)[0].transpose(1, 2, 0) if np.asarray(synth).ndim == 4 else np.asarray(synth)
    flow = seq.flow(k)
    top = max(np.nanpercentile(np.linalg.norm(flow, axis=-1), 95), 1.0)
    mask = seq.mask(k)
    panels = [("rendered RGB", seq.image(k)),
              ("exact depth", cv2.applyColorMap(np.clip(255 - depth * 6, 0, 255).astype(np.uint8), cv2.COLORMAP_MAGMA)[..., ::-1]),
              ("exact flow to the next frame", flow_to_rgb(flow, top)),
              ("movers (instance masks)", np.where(mask[..., None] > 0, np.array([230, 80, 40], np.uint8), seq.image(k) // 3)),
              ("flow synthesized from this frame's depth\nand a sampled motion (training data)", flow_to_rgb(synth, top * 2))]
    fig = new_figure((12.0, 4.6), dpi=100)
    grid = fig.add_gridspec(2, 3)
    spots = [grid[0, 0], grid[0, 1], grid[0, 2], grid[1, 0], grid[1, 1]]
    for (title, img), spot in zip(panels, spots):
        ax = fig.add_subplot(spot)
        ax.imshow(img)
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    ax = fig.add_subplot(grid[1, 2])
    ax.axis("off")
    ax.text(0.0, 0.5, "single frames + depth + motion model\n-> synthetic flow -> flow-to-6DoF network\n"
                      "-> odometry + BoVW loops + gtsam pose graph\n-> SLAM, scored on KITTI / EuRoC / TUM",
            fontsize=9, va="center")
    fig.tight_layout()
    out = save_figure(fig, REPO / "docs" / "img" / "overview.png", dpi=100)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
