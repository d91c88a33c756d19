#!/usr/bin/env bash
# The device check, for a bare GPU machine (no network needed beyond what is installed there).
# In under 10 minutes: the GPU tests, then NN_cons trained on the same toy samples with the same seed
# and sample budget on the CPU and on the GPU (samples/s of both and the held-out loss difference),
# and flow synthesis samples/s on both (bench/bench_device.py). Prints one table; exit 0 when it ran.
#   bash scripts/device_check.sh            # uses .venv if present, else the system python3
set -euo pipefail
cd "$(dirname "$0")/.."
export MUJOCO_GL=${MUJOCO_GL:-egl} PYOPENGL_PLATFORM=${PYOPENGL_PLATFORM:-egl}
PY=${PY:-}
if [ -z "$PY" ]; then
  if [ -x .venv/bin/python ]; then PY=.venv/bin/python; else PY=python3; fi
fi
echo "== python: $($PY --version 2>&1) at $PY"
if ! $PY -c "import torch" 2>/dev/null; then
  echo "torch is not installed for $PY; install the CUDA build first (pip install torch==2.13.0)" >&2
  exit 2
fi
$PY - <<'EOF'
import torch
print(f"== torch {torch.__version__}, CUDA available: {torch.cuda.is_available()}"
      + (f", {torch.cuda.device_count()} x {torch.cuda.get_device_name(0)}" if torch.cuda.is_available() else ""))
EOF
# deepslam itself (its pure-Python dependencies must already be there: the GPU machine has no index)
if ! $PY -c "import deepslam" 2>/dev/null; then
  $PY -m pip install --no-deps --no-build-isolation -q -e . || { echo "cannot install deepslam for $PY" >&2; exit 2; }
fi
echo "== GPU tests (they skip with a reason where no GPU is present)"
timeout 240 $PY -m pytest -q -p no:cacheprovider -k "cuda or device" tests/vo tests/gen 2>&1 | tail -15 || true
echo "== training and synthesis on each device (bench/bench_device.py)"
timeout 300 $PY - <<'EOF'
import json
from bench import bench_device
rows = bench_device.run(quick=False)
for r in rows:
    extra = {k: r[k] for k in ("val_loss", "val_loss_vs_cpu", "note") if k in r}
    ratio = f"  x{r['ratio']:.2f} vs {r['baseline']}" if r.get("ratio") is not None else ""
    print(f"{r['name']}: {r['value']} {r['unit']}{ratio}  {json.dumps(extra)}")
EOF
