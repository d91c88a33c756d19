"""runtime: what every torch stage of deepslam shares, below the learning stack (core <- runtime <- gen).

- :mod:`runtime.device`: which torch device to compute on (``--device auto|cpu|cuda[:N]``).
- :mod:`runtime.training`: the training runner shared by ``vo.train`` and ``flow.train`` (the output folder's
  lock, caps, checkpoints, resume, divergence checks, history, TensorBoard).
"""
