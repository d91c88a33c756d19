"""Training and flow synthesis on each torch device present, against the CPU in the same run.

Rows: NN_cons training samples/s for a fixed sample budget of toy flows (the same seed and budget on
every device; the held-out loss of each device's model against the CPU's), and flow synthesis
samples/s (gen.flow.synthesize_flow, torch backend) per device. Where no CUDA device is present the
CUDA rows say so (value None). On the CPU the figures are also the baseline of the data-parallel
path: one process against two ranks on the same two cores (gloo), both at the same budget.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch


def _train(device: str, samples: int, out: Path, ranks: int = 1) -> dict:
    argv = ["-m", "deepslam", "train", "--mode", "synthetic", "--toy", str(samples + 2000), "--net", "cpu",
            "--max-samples", str(samples), "--nll-epochs", "1", "--batch", "64", "--seed", "0", "--quiet",
            "--json", "--device", device, "--out", str(out)]
    if ranks > 1:
        argv = ["-m", "torch.distributed.run", "--nproc_per_node", str(ranks), *argv, "--threads", "1"]
    env = {**os.environ, "OMP_NUM_THREADS": "1" if ranks > 1 else os.environ.get("OMP_NUM_THREADS", "2")}
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, *argv], capture_output=True, text=True, env=env)
    if r.returncode != 0:
        raise RuntimeError(r.stderr.strip().splitlines()[-1] if r.stderr.strip() else f"exit {r.returncode}")
    hist = json.loads((out / "history.json").read_text())
    stage1 = [h for h in hist if h["stage"] == 1]
    n = sum(h["samples"] for h in stage1)
    return {"sps": n / sum(h["seconds"] for h in stage1), "val_loss": stage1[-1]["val_loss"],
            "wall_s": time.perf_counter() - t0}


def _synthesis_sps(device: str, n: int) -> float:
    from deepslam.gen.flow import synthesize

    dev = torch.device(device)
    rng = np.random.default_rng(0)
    depth = torch.from_numpy(rng.uniform(2, 40, (n, 192, 640)).astype(np.float32)).to(dev)
    k = np.array([370.9, 370.9, 319.5, 95.5])
    motion = np.tile(np.eye(4), (n, 1, 1))
    motion[:, 2, 3] = -1.0
    synthesize(depth[:2], k, motion[:2], backend="torch")  # warm-up
    if dev.type == "cuda":
        torch.cuda.synchronize()
    t0 = time.perf_counter()
    synthesize(depth, k, motion, backend="torch")
    if dev.type == "cuda":
        torch.cuda.synchronize()
    return n / (time.perf_counter() - t0)


def run(quick: bool = False) -> list[dict]:
    samples = 2000 if quick else 8000
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        cpu = _train("cpu", samples, Path(tmp) / "cpu")
        rows.append({"name": f"NN_cons training, {samples} toy samples, cpu", "value": round(cpu["sps"], 1),
                     "unit": "samples/s", "baseline": None, "baseline_value": None, "ratio": None,
                     "target": None, "met": None, "val_loss": cpu["val_loss"]})
        ddp = _train("cpu", samples, Path(tmp) / "ddp", ranks=2)
        rows.append({"name": f"NN_cons training, {samples} toy samples, cpu, 2 data-parallel ranks (gloo)",
                     "value": round(ddp["sps"], 1), "unit": "samples/s", "baseline": "cpu, one process",
                     "baseline_value": round(cpu["sps"], 1), "ratio": ddp["sps"] / cpu["sps"], "target": None,
                     "met": None, "val_loss": ddp["val_loss"],
                     "note": "same two cores: the ranks share them, so this measures the overhead, not a gain"})
        if torch.cuda.is_available():
            gpu = _train("cuda", samples, Path(tmp) / "cuda")
            rows.append({"name": f"NN_cons training, {samples} toy samples, cuda", "value": round(gpu["sps"], 1),
                         "unit": "samples/s", "baseline": "cpu", "baseline_value": round(cpu["sps"], 1),
                         "ratio": gpu["sps"] / cpu["sps"], "target": None, "met": None,
                         "val_loss": gpu["val_loss"], "val_loss_vs_cpu": gpu["val_loss"] - cpu["val_loss"]})
        else:
            rows.append({"name": "NN_cons training, cuda", "value": None, "unit": "samples/s", "baseline": "cpu",
                         "baseline_value": round(cpu["sps"], 1), "ratio": None, "target": None, "met": None,
                         "note": "no CUDA device here (torch.cuda.is_available() is False)"})
    n = 8 if quick else 32
    cpu_syn = _synthesis_sps("cpu", n)
    rows.append({"name": "flow synthesis 192x640 (torch backend), cpu", "value": round(cpu_syn, 1), "unit": "samples/s",
                 "baseline": None, "baseline_value": None, "ratio": None, "target": None, "met": None})
    if torch.cuda.is_available():
        g = _synthesis_sps("cuda", n * 8)
        rows.append({"name": "flow synthesis 192x640 (torch backend), cuda", "value": round(g, 1), "unit": "samples/s",
                     "baseline": "cpu", "baseline_value": round(cpu_syn, 1), "ratio": g / cpu_syn, "target": None,
                     "met": None})
    return rows
