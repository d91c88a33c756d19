"""Flow synthesis throughput (gen.flow.synthesize) against the per-sample NumPy reference and the memory bound.

Setting of the issue: 96x320 depth maps, batch 128, float32, 2 threads. The default backend on CPU is
the fused numba kernel (:mod:`gen.flow`); the torch element-wise path is measured beside it. Rows:

- throughput vs. target (>= 20,000 samples/s), with the ratio to the memory-bandwidth bound: depth in
  (4 B/px) + flow out (8 B/px) = 12 B/px at the copy bandwidth measured in the same run;
- speed-up over the straightforward per-sample NumPy implementation (gen.flow_reference, float64),
  measured in the same run (target >= 15x);
- the measured bandwidth, the cost of a fresh output allocation (no ``out=``), the z-buffer path and the
  on-the-fly dataset (``SyntheticFlowDataset.get_batch``) for context.

The synthesis is measured in fresh interpreters with OpenMP's wait policy PASSIVE and ACTIVE (read
once at start-up; on shared cores, spinning threads waste the time slices the others need) and in
this process as configured; the best is the headline and all are in its ``note``, each a median of
repeated runs with the 1-minute load average. The machine's 2 cores are shared with other work.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.core.paths import base_dir

B, H, W = 128, 96, 320
TARGET_SPS = 20_000.0
TARGET_SPEEDUP = 15.0


def _median_time(fn, repeats: int, warmup: int = 2) -> tuple[float, float]:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), float(np.min(times))


def _inputs(rng: np.random.Generator):
    # Depth: a road below the horizon and a facade at 8-40 m above it, with some holes (0 = none).
    v = np.arange(H, dtype=np.float64)[:, None] - (H - 1) / 2.0
    road = np.where(v > 1, 200.0 * 1.65 / np.maximum(v, 1e-3), 0.0)
    depth = np.empty((B, H, W), np.float32)
    for b in range(B):
        facade = rng.uniform(8, 40) + rng.normal(0, 0.2, (H, W))
        d = np.where(road > 0, np.minimum(road, facade), facade)
        d[rng.random((H, W)) < 0.02] = 0.0
        depth[b] = d
    vec = np.concatenate([rng.normal(0, 0.005, (B, 3)), rng.normal([0.0, 0.0, -0.9], [0.02, 0.02, 0.3], (B, 3))], axis=1)
    return depth, se3.from_euler6(vec)


def _bandwidth_gbs(quick: bool) -> float:
    """Copy bandwidth in GB/s (bytes read + written), the better of a NumPy copy and a 2-thread torch copy."""
    import torch

    n = (64 if quick else 256) * 2 ** 20 // 4
    a = np.random.default_rng(0).random(n, dtype=np.float32)
    b = np.empty_like(a)
    t_np, _ = _median_time(lambda: np.copyto(b, a), 5 if quick else 10)
    ta, tb = torch.from_numpy(a), torch.from_numpy(b)
    t_t, _ = _median_time(lambda: tb.copy_(ta), 5 if quick else 10)
    return 2 * a.nbytes / min(t_np, t_t) / 1e9


def _measure_synthesis(quick: bool) -> dict:
    """Samples/s of gen.flow.synthesize in THIS process with torch on 2 threads (out=, fresh, z-buffer)."""
    import torch

    from deepslam.gen.flow import synthesize

    old_threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        depth_np, motions = _inputs(np.random.default_rng(0))
        depth = torch.from_numpy(depth_np)
        cam = PinholeCamera(W, H, 200.0, 200.0, (W - 1) / 2.0, (H - 1) / 2.0)
        out = (torch.empty(B, 2, H, W), torch.empty(B, H, W, dtype=torch.bool))
        reps = 10 if quick else 40
        t_out, best = _median_time(lambda: synthesize(depth, cam, motions, out=out), reps, warmup=3)
        t_torch, _ = _median_time(lambda: synthesize(depth, cam, motions, out=out, backend="torch"), reps, warmup=3)
        t_alloc, _ = _median_time(lambda: synthesize(depth, cam, motions), reps)
        # the z-buffer against the plain synthesis in turn (so that load from other processes hits both alike)
        synthesize(depth, cam, motions, zbuffer=True, out=out)
        t_pair = {True: [], False: []}
        for _ in range(4 if quick else 9):
            for zb in (False, True):
                t0 = time.perf_counter()
                synthesize(depth, cam, motions, zbuffer=zb, out=out)
                t_pair[zb].append(time.perf_counter() - t0)
        t_zb, t_plain_pair = float(np.median(t_pair[True])), float(np.median(t_pair[False]))
        dataset_sps = _dataset_sps(quick)
        # CPU time on one thread: what one core does, whatever else runs on the machine.
        torch.set_num_threads(1)
        cpu = []
        for _ in range(3 if quick else 10):
            c0 = time.process_time()
            synthesize(depth, cam, motions, out=out)
            cpu.append(time.process_time() - c0)
    finally:
        torch.set_num_threads(old_threads)
    return {"sps": B / t_out, "best_sps": B / best, "torch_sps": B / t_torch, "alloc_sps": B / t_alloc, "zbuffer_sps": B / t_zb,
            "zbuffer_plain_sps": B / t_plain_pair,
            "dataset_sps": dataset_sps, "cpu_sps_per_core": B / float(np.median(cpu)), "load": os.getloadavg()[0]}


def _measure_in_subprocess(quick: bool, wait_policy: str) -> dict | None:
    """:func:`_measure_synthesis` in a fresh interpreter with ``OMP_WAIT_POLICY`` set (OpenMP reads it
    once, at start-up): PASSIVE lets waiting threads sleep, which matters when the cores are shared."""
    env = {**os.environ, "OMP_WAIT_POLICY": wait_policy, "OMP_NUM_THREADS": "2"}
    cmd = [sys.executable, "-m", "bench.bench_gen", "--worker"] + (["--quick"] if quick else [])
    try:
        res = subprocess.run(cmd, cwd=base_dir(), env=env, capture_output=True, text=True, timeout=900)
        return json.loads(res.stdout.strip().splitlines()[-1]) if res.returncode == 0 else None
    except (subprocess.TimeoutExpired, json.JSONDecodeError, IndexError):
        return None


def run(quick: bool = False) -> list[dict]:
    from deepslam.gen.flow_reference import synthesize_reference

    runs = {}
    for policy in ("PASSIVE", "ACTIVE"):
        got = _measure_in_subprocess(quick, policy)
        if got is not None:
            runs[f"fresh process, OMP_WAIT_POLICY={policy}"] = got
    runs["this process, OpenMP as configured"] = _measure_synthesis(quick)
    setting, best = max(runs.items(), key=lambda kv: kv[1]["sps"])
    sps = best["sps"]

    depth_np, motions = _inputs(np.random.default_rng(0))
    cam = PinholeCamera(W, H, 200.0, 200.0, (W - 1) / 2.0, (H - 1) / 2.0)
    n_ref = 4 if quick else 16
    t_ref, _ = _median_time(lambda: [synthesize_reference(depth_np[i], cam, motions[i]) for i in range(n_ref)],
                            3 if quick else 5, warmup=1)
    sps_ref = n_ref / t_ref
    cpu_ref = []
    for _ in range(3 if quick else 5):
        c0 = time.process_time()
        for i in range(n_ref):
            synthesize_reference(depth_np[i], cam, motions[i])
        cpu_ref.append(time.process_time() - c0)
    cpu_sps_ref = n_ref / float(np.median(cpu_ref))
    cpu_sps = max(v["cpu_sps_per_core"] for v in runs.values())
    bw = _bandwidth_gbs(quick)
    bound = bw * 1e9 / (12.0 * H * W)
    settings = "; ".join(f"{k}: {v['sps']:.0f}/s (best {v['best_sps']:.0f}, load {v['load']:.2f})" for k, v in runs.items())
    note = f"batch {B}, {H}x{W}, float32, 2 threads, out= buffers, default backend (numba); best setting: {setting}; all: {settings}"
    return [
        {"name": "flow synthesis throughput (96x320, b128, fp32, 2 threads)", "value": round(sps, 1),
         "unit": "samples/s", "baseline": "memory-bandwidth bound (12 B/px at the measured copy bandwidth)",
         "baseline_value": round(bound, 1), "ratio": sps / bound, "target": ">= 20000 samples/s",
         "met": bool(sps >= TARGET_SPS), "note": note},
        {"name": "flow synthesis vs per-sample NumPy", "value": round(sps, 1), "unit": "samples/s",
         "baseline": "per-sample NumPy reference (gen.flow_reference, float64)", "baseline_value": round(sps_ref, 1),
         "ratio": sps / sps_ref, "target": ">= 15x", "met": bool(sps / sps_ref >= TARGET_SPEEDUP)},
        {"name": "memory bandwidth (large copy, read + write)", "value": round(bw, 2), "unit": "GB/s",
         "baseline": None, "baseline_value": None, "ratio": None, "target": None, "met": None},
        {"name": "flow synthesis, fused numba kernel (the default on CPU) vs torch element-wise ops",
         "value": round(sps, 1), "unit": "samples/s", "baseline": "backend='torch' (same process, same threads)",
         "baseline_value": round(best["torch_sps"], 1), "ratio": sps / best["torch_sps"], "target": None, "met": None},
        {"name": "flow synthesis, fresh outputs (no out=)", "value": round(best["alloc_sps"], 1), "unit": "samples/s",
         "baseline": "with out= buffers", "baseline_value": round(sps, 1), "ratio": best["alloc_sps"] / sps,
         "target": None, "met": None},
        {"name": "flow synthesis with z-buffer (occlusion-aware; interleaved with the plain synthesis)",
         "value": round(best["zbuffer_sps"], 1), "unit": "samples/s",
         "baseline": "without z-buffer, the same runs in turn", "baseline_value": round(best["zbuffer_plain_sps"], 1),
         "ratio": best["zbuffer_sps"] / best["zbuffer_plain_sps"], "target": ">= 0.25",
         "met": bool(best["zbuffer_sps"] / best["zbuffer_plain_sps"] >= 0.25)},
        {"name": "flow synthesis per core, by CPU time (1 thread; insensitive to other load)",
         "value": round(cpu_sps, 1), "unit": "samples/s/core", "baseline": "per-sample NumPy reference, by CPU time",
         "baseline_value": round(cpu_sps_ref, 1), "ratio": cpu_sps / cpu_sps_ref, "target": None, "met": None,
         "note": f"two dedicated cores at this rate would give {2 * cpu_sps:.0f} samples/s"},
        {"name": "SyntheticFlowDataset.get_batch (376x1241 frames -> 96x320, b128)",
         "value": round(best["dataset_sps"], 1), "unit": "samples/s", "baseline": "flow synthesis alone",
         "baseline_value": round(sps, 1), "ratio": best["dataset_sps"] / sps, "target": None, "met": None},
    ]


def _dataset_sps(quick: bool) -> float:
    """SyntheticFlowDataset.get_batch samples/s from in-memory 376x1241 frames to 96x320 (motion draws,
    depth resampling (cached per frame), synthesis, targets)."""
    from deepslam.gen.dataset import ArrayDepthFrames, DatasetConfig, SyntheticFlowDataset
    from deepslam.gen.motion import MotionModel, SixDof, StudentT

    cam = PinholeCamera(1241, 376, 718.856, 718.856, 607.19, 185.22)
    rng = np.random.default_rng(1)
    frames = ArrayDepthFrames(rng.uniform(3, 60, (8, 376, 1241)).astype(np.float32), cam, "random")
    six = SixDof(tuple([StudentT(3.0, 0.0, 0.002, -0.05, 0.05)] * 3 + [StudentT(3.0, 0.0, 0.01, -0.2, 0.2)] * 2
                       + [StudentT(3.0, -0.9, 0.3, -3.0, 0.5)]), 1000)
    ds = SyntheticFlowDataset(frames, MotionModel(1, six), 100_000, seed=0, config=DatasetConfig(resolution_hw=(H, W)))
    start = [0]

    def batch():
        ds.get_batch(range(start[0], start[0] + B))
        start[0] += B

    t, _ = _median_time(batch, 3 if quick else 8, warmup=1)
    return B / t


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--worker", action="store_true", help="measure synthesis in this process, print JSON")
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    if a.worker:
        print(json.dumps(_measure_synthesis(a.quick)))
    else:
        for row in run(a.quick):
            print(json.dumps(row))
