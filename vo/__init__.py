"""Learned visual odometry (Slinko et al., 2019): optical flow -> 6DoF relative motion with uncertainty.

Laid out by field:

- the network: :mod:`vo.net` (the paper's six convolutions, two fully connected branches, per-DoF log-std
  heads; presets), :mod:`vo.ensemble` (seed ensembles).
- :mod:`vo.data`: its training data: single frames with depth (:mod:`vo.data.frames`), motion samplers
  (:mod:`vo.data.motion`), synthetic flow from frames + motion (:mod:`vo.data.synthetic`,
  :mod:`vo.data.recipe`), supervised frame pairs (:mod:`vo.data.supervised`), ``deepslam train``'s sources
  (:mod:`vo.data.sources`), tensor samples and per-epoch seeds (:mod:`vo.data.samples`), toy plane flow
  (:mod:`vo.data.toy`), network inputs computed ahead (:mod:`vo.data.prefetch`).
- training: :mod:`vo.train` (the paper's two-stage recipe, checkpoints and resume), :mod:`vo.trainconfig`,
  :mod:`vo.distributed` (torchrun), :mod:`vo.adapt` (a sequence's single frames, no poses).
- :mod:`vo.geometry`: inference geometry beside the network: the epipolar pose, the road's scale, pose from
  flow and depth.
- :mod:`vo.modelfiles`: model files (safetensors IO, their tree, the shipped models, legacy conversion).
- running it: :mod:`vo.odometry` (a model file as a predictor or an odometry: the one way to load one),
  :mod:`vo.infer` (:class:`~vo.infer.VOPredictor`, batched inference, chaining), :mod:`vo.pipeline`
  (:func:`~vo.pipeline.run_vo`, what ``deepslam vo`` runs) and :mod:`vo.report` (its motions table, metrics
  and summary).

The 6DoF vector everywhere is the paper's ``(euler_x, euler_y, euler_z, t_x, t_y, t_z)`` of
``cam_{t+k}_from_cam_t`` (radians, metres, R = Rz Ry Rx, OpenCV camera axes), see :mod:`core.se3`.
"""
