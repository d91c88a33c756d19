"""gen: training data for flow-based odometry from single frames (Slinko et al., 2019).

Modules (import the one you need; nothing heavy is imported here):

- :mod:`gen.flow`: flow synthesis from depth + SE3 (batched torch), z-buffer occlusion, normalised flow.
- :mod:`gen.flow_reference`: the same in plain per-sample NumPy (tests, benchmark baseline).
- :mod:`gen.motion`: Student-t motion model per DoF (fit on ground truth, JSON, sampling), loop motions,
  the paper's Figure 3.
- :mod:`gen.stereo`: depth from stereo (OpenCV StereoSGBM or DIS flow) with a left-right check.
- :mod:`gen.dataset`: :class:`~gen.dataset.SyntheticFlowDataset`, an on-the-fly torch Dataset.
- :mod:`gen.shards`: ``deepslam gen``: deterministic tar shards (WebDataset layout) + manifest,
  local process pool or Ray backend, resumable.
- :mod:`gen.validate`: synthesized flow vs. a simulator's true flow (end-to-end geometry check).
- :mod:`gen.novel_view`: the image a moved camera would see, rendered from one frame + depth (so a flow
  estimator can run on a synthetic pair: training on the flow the network will really be given).

The torch device choice and the training runner live in :mod:`deepslam.runtime`.
"""
