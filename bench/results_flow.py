"""The learned flow estimator against DIS: held-out renders and real KITTI.

- Held-out renders (sequences no flow model trained on): EPE (px) and Fl-all (KITTI 2015's outlier
  rate: EPE > 3 px and > 5 % of the true flow) against the simulator's exact flow, consecutive pairs.
- Real KITTI slices (no ground-truth flow): forward-backward consistency (share of pixels whose
  forward flow, followed by the backward flow at its landing point, returns within max(1 px, 5 % of
  the flow)) and the photometric error (mean absolute grey difference between frame t and frame t+1
  sampled at x + flow, pixels landing inside the image), per estimator on the same pairs.
- Frames/s of each estimator on 1241x376 KITTI pairs (this machine, the threads torch and OpenCV use).
- On the renders also EPE and Fl-all at the odometry's input size (``--net-size``, 96x320): both flows
  resized as the network's input is (:func:`flow.estimators.resize_flow`), what the odometry reads.

Writes ``out/results/flow/results.json`` and ``results.md``. Usage::

    python -m bench.results_flow [--model models/flow_learned.safetensors] [--held DIR ...]

Estimators: DIS medium, DIS medium on frames downscaled to each ``--dis-widths`` width (``dis-medium-w640``:
:class:`flow.estimators.DISFlow`'s ``max_width``), the learned network, and the learned network's flow as
DIS's start (``learned-dis``, :class:`flow.net.LearnedDISFlow`), all on the same pairs.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from bench.stamp import write_stamp
from deepslam.core import atomic
from deepslam.core.paths import out_dir, shared_data_dir
from deepslam.core.readers import open_sequence


def fb_consistency(fw: np.ndarray, bw: np.ndarray) -> float:
    """Share of pixels whose forward flow ``fw`` (H, W, 2) and the backward flow ``bw`` sampled at the
    landing point cancel within max(1 px, 5 % of |fw|) (pixels landing outside left out)."""
    from deepslam.flow.estimators import forward_backward_error

    err = forward_backward_error(fw, bw)  # forward then backward: 0 where they agree, NaN landing outside
    inside = np.isfinite(err)
    ok = err <= np.maximum(1.0, 0.05 * np.linalg.norm(fw, axis=-1))
    return float(ok[inside].mean()) if inside.any() else float("nan")


def photometric_error(g0: np.ndarray, g1: np.ndarray, fw: np.ndarray) -> float:
    """Mean |g0(x) - g1(x + fw(x))| (grey levels) over pixels landing inside frame 1."""
    import cv2

    h, w = g0.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    mu, mv = u + fw[..., 0], v + fw[..., 1]
    inside = (mu >= 0) & (mu <= w - 1) & (mv >= 0) & (mv <= h - 1)
    warped = cv2.remap(g1.astype(np.float32), mu, mv, cv2.INTER_LINEAR)
    return float(np.abs(g0.astype(np.float32) - warped)[inside].mean())


HELD = (("street", "car", 211, 40, 620), ("street", "car", 212, 40, 620), ("room", "drone", 213, 40, 376))
"""Held-out renders made when ``--held`` is not given: (scene, trajectory, seed, frames, width); the default
street is the KITTI-look one; the training scripts here render no sequence with these seeds."""


def main(argv: list[str] | None = None) -> int:
    from deepslam.flow.estimators import DISFlow, resize_flow
    from deepslam.flow.images import to_grey
    from deepslam.flow.metrics import endpoint_error
    from deepslam.flow.net import LearnedDISFlow, LearnedFlow

    ap = argparse.ArgumentParser(prog="python -m bench.results_flow")
    ap.add_argument("--model", default=None, help="learned flow model (default: the shipped one)")
    ap.add_argument("--held", nargs="*", default=None,
                    help="held-out rendered sequences (default: two default streets and a room no flow model trained "
                         "on, rendered into OUT/held if missing: " + ", ".join(f"{s} seed {n}" for s, _, n, _, _ in HELD) + ")")
    ap.add_argument("--pairs", type=int, default=30, help="pairs per sequence (evenly spread)")
    ap.add_argument("--dis-widths", default="640", help="comma-separated widths DIS also runs at (frames downscaled; "
                    "'' for none)")
    ap.add_argument("--net-size", default="96x320", help="HxW the odometry reads, for the EPE at its input size")
    ap.add_argument("--out", default=str(out_dir() / "results" / "flow"))
    args = ap.parse_args(argv)
    try:
        widths = [int(w) for w in args.dis_widths.split(",") if w.strip()]
        net_h, net_w = (int(x) for x in args.net_size.lower().split("x"))
    except ValueError:
        ap.error(f"--dis-widths must be integers and --net-size HxW, got {args.dis_widths!r}, {args.net_size!r}")
    learned = LearnedFlow(args.model)
    ests = {"dis-medium": DISFlow("medium")}
    for w in widths:
        dis = DISFlow("medium", max_width=w)
        ests[dis.name] = dis
    ests.update({"learned": learned, "learned-dis": LearnedDISFlow(args.model)})
    if args.held is None:
        from deepslam.studies.demo import render_once

        log: list[str] = []
        held = [str(render_once(scene, traj, frames, width, seed, Path(args.out) / "held" / f"{scene}_s{seed}", log))
                for scene, traj, seed, frames, width in HELD]
    else:
        held = args.held
    rows = []
    for d in held:
        seq = open_sequence(d)
        idx = np.unique(np.linspace(0, len(seq) - 2, min(args.pairs, len(seq) - 1)).astype(int))
        for name, est in ests.items():
            epe, fl, epe_net, fl_net = [], [], [], []
            for i in idx:
                pred, gt = est.pair_flow(seq, int(i), int(i) + 1), seq.flow(int(i))
                r = endpoint_error(pred, gt)
                epe.append(r["epe"])
                fl.append(r["fl_all"])
                r = endpoint_error(resize_flow(pred, net_w, net_h, "nan"), resize_flow(gt, net_w, net_h, "nan"))
                epe_net.append(r["epe"])
                fl_net.append(r["fl_all"])
            rows.append({"data": f"held-out render {Path(d).parent.name}/{Path(d).name} ({seq.camera.width}x{seq.camera.height})",
                         "estimator": name, "pairs": len(idx), "epe_px": float(np.mean(epe)), "fl_all": float(np.mean(fl)),
                         "epe_net_px": float(np.mean(epe_net)), "fl_all_net": float(np.mean(fl_net))})
    shared = shared_data_dir()
    for sl in ("06", "07"):
        root = shared / "kitti" / "sequences" / sl
        if not root.is_dir():
            continue
        seq = open_sequence(root)
        idx = np.unique(np.linspace(0, len(seq) - 2, min(args.pairs, len(seq) - 1)).astype(int))
        greys = {}
        for name, est in ests.items():
            fb, ph, secs = [], [], 0.0
            for i in idx:
                g0 = greys.setdefault(int(i), to_grey(seq.image(int(i))))
                g1 = greys.setdefault(int(i) + 1, to_grey(seq.image(int(i) + 1)))
                t0 = time.perf_counter()
                fw = est.estimate(g0, g1)
                secs += time.perf_counter() - t0
                bw = est.estimate(g1, g0)
                fb.append(fb_consistency(fw, bw))
                ph.append(photometric_error(g0, g1, fw))
            rows.append({"data": f"KITTI {sl} (real, {seq.camera.width}x{seq.camera.height})", "estimator": name,
                         "pairs": len(idx), "fb_consistent": float(np.mean(fb)), "photometric_err": float(np.mean(ph)),
                         "frames_per_s": len(idx) / secs})
    res = {"model": str(args.model or "shipped"), "meta": learned.meta, "net_size": [net_h, net_w], "rows": rows}
    out = Path(args.out)
    atomic.write_json(out / "results.json", res)
    lines = [f"| data | estimator | pairs | EPE px | Fl-all | EPE px at {net_h}x{net_w} | Fl-all at {net_h}x{net_w} | "
             "fwd-bwd consistent | photometric err | frames/s |", "|---|---|---|---|---|---|---|---|---|---|"]
    def cell(r: dict, key: str, fmt: str) -> str:
        return fmt % r[key] if key in r else ""

    for r in rows:
        lines.append(f"| {r['data']} | {r['estimator']} | {r['pairs']} | {cell(r, 'epe_px', '%.2f')} | "
                     f"{cell(r, 'fl_all', '%.3f')} | {cell(r, 'epe_net_px', '%.2f')} | {cell(r, 'fl_all_net', '%.3f')} | "
                     f"{cell(r, 'fb_consistent', '%.3f')} | "
                     f"{cell(r, 'photometric_err', '%.2f')} | {cell(r, 'frames_per_s', '%.1f')} |")
    atomic.write_text(out / "results.md", "\n".join(lines) + "\n")
    write_stamp(out, model=str(args.model or "models/flow_learned.safetensors"))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
