"""Learned visual odometry (Slinko et al., 2019): optical flow -> 6DoF relative motion with uncertainty.

Modules:

- :mod:`flow.estimators`: flow between two images behind one interface (OpenCV DIS, the
  simulator's ground-truth flow, a registry for learned estimators), and resizing a flow to the
  network's input with its values rescaled.
- :mod:`vo.net`: the paper's network (six convolutions, two fully connected branches, per-DoF
  log-std heads), configurable in width, depth and resolution.
- training data: :mod:`vo.data.samples` (tensor samples, shards, hold-out split, per-epoch seeds),
  :mod:`vo.data.frames` (single frames with depth from sequences), :mod:`vo.data.motion` (motion samplers),
  :mod:`vo.data.synthetic` (synthetic flow from frames + motion, via gen), :mod:`vo.data.supervised` (flow
  between real frames + ground-truth poses), :mod:`vo.data.toy` (plane-flow samples for tests).
- :mod:`vo.train`: the paper's two-stage training recipe with checkpoints and resume.
- :mod:`vo.infer`: :class:`~vo.infer.VOPredictor`, batched inference and trajectory chaining.
- :mod:`vo.modelfiles.models`: the models shipped in ``models/``.

The 6DoF vector everywhere is the paper's ``(euler_x, euler_y, euler_z, t_x, t_y, t_z)`` of
``cam_{t+k}_from_cam_t`` (radians, metres, R = Rz Ry Rx, OpenCV camera axes), see :mod:`core.se3`.
"""
