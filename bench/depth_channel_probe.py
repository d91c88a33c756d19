"""Does a depth-channel network take its distance from the depth it is given? A probe, not a table's figure.

For each depth-channel model of the RGB-D rows (``bench.results_repro_rgbd``'s ``*_depth_cons_s0``), on the
unseen rendered room's pairs (0-1, 2-3, ...; the simulator's exact flow, the room's Kinect-like depth), the
network's own translation is predicted with the frame's inverse depth as given, doubled (the scene twice as
close: a network that reads scale from its depth predicts half the translation, the geometry's x0.5) and zeroed;
the figure is the median over pairs of ``|t(changed)| / |t(as given)|``. (The first convolution's weights are no
guide: their RMS per input channel stays at 0.98-1.19x its initial value, the depth channel's at 0.98-1.00x, in
every model.)

    python -m bench.depth_channel_probe [--room out/results/repro_rgbd/room_s51] [--models bench/paper_recipe]

Prints a markdown table; writes nothing.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from deepslam.core.readers import open_sequence
from deepslam.flow import registry
from deepslam.vo.data.frames import frame_inverse_depth
from deepslam.vo.infer import VOPredictor

MODELS = ("room_synthetic_mirror_depth_cons_s0", "room_synthetic_speedscale_mirror_depth_cons_s0",
          "room_supervised_depth_cons_s0")
"""The RGB-D rows' depth-channel models (folders under ``--models``), seed 0."""


def probe(predictor: VOPredictor, flows: np.ndarray, intr: np.ndarray, inv: np.ndarray) -> dict:
    """Figures of one model. flows (P, 2, h, w) float32 px, intr (P, 4) px, inv (P, 1, h, w) float32 1/m, all
    at the network's resolution. Returns ``{"x2": median ratio, "zero": median ratio}``."""
    t_norm = {}
    for name, k in (("given", 1.0), ("x2", 2.0), ("zero", 0.0)):
        mean6, _ = predictor.predict(flows, intr, inv * k)
        t_norm[name] = np.linalg.norm(mean6[:, 3:], axis=1)
    ok = t_norm["given"] > 1e-6
    return {"x2": float(np.median(t_norm["x2"][ok] / t_norm["given"][ok])),
            "zero": float(np.median(t_norm["zero"][ok] / t_norm["given"][ok]))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--room", default="out/results/repro_rgbd/room_s51",
                    help="the unseen room (bench.results_repro_rgbd renders it)")
    ap.add_argument("--models", default="bench/paper_recipe", help="folder of the trained models")
    args = ap.parse_args(argv)
    room = Path(args.room)
    if not (room / "sequence.json").is_file() and not (room / "poses.txt").is_file():
        print(f"{room}: no rendered room here (run python -m bench.results_repro_rgbd first)", file=sys.stderr)
        return 2
    seq = open_sequence(room)
    est = registry.make("gt")
    pairs = [(i, i + 1) for i in range(0, len(seq) - 1, 2)]
    print("| model | samples | inverse depth x2 (ideal 0.5) | zeroed |")
    print("|---|---|---|---|")
    for name in MODELS:
        folder = Path(args.models) / name
        path = folder / "model.safetensors"
        if not path.is_file():
            continue
        pred = VOPredictor.from_file(path, bf16=False, channels_last=False)
        h, w = pred.input_size
        flows = np.zeros((len(pairs), 2, h, w), np.float32)
        intr = np.zeros((len(pairs), 4), np.float32)
        inv = np.zeros((len(pairs), 1, h, w), np.float32)
        for k, (i, j) in enumerate(pairs):
            flows[k], intr[k] = pred.prepare(est.pair_flow(seq, i, j), seq.camera)
            inv[k] = frame_inverse_depth(seq, i, w, h)
        r = probe(pred, flows, intr, inv)
        samples = pred.meta.get("summary", {}).get("train_samples", "?")
        print(f"| {name} | {samples:,} | {r['x2']:.3f} | {r['zero']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
