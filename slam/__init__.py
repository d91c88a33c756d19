"""SLAM from learned odometry (Slinko et al., 2019): relocalization, pose graph, pipeline, tuning.

- :mod:`slam.odometry`: the :class:`~slam.odometry.Odometry` protocol the pipeline consumes
  (``predict(seq, pairs) -> (mean6, std6)`` of ``cam_j_from_cam_i``) and a ground-truth odometry with
  known noise for tests.
- :mod:`slam.reloc`: SIFT, BoW vocabulary (k-means, tf-idf), fast retrieval, ratio test + N_th +
  essential-matrix check.
- :mod:`slam.posegraph`: gtsam Pose3 graph with the paper's covariances carried into gtsam's tangent
  space, robust kernels, pruning of false loops, Levenberg-Marquardt.
- :mod:`slam.pipeline`: odometry -> relocalization -> pose graph on any core Sequence.
- :mod:`slam.tune`: grid / coordinate search of C_s, C_r, T_loop ranked by ATE.
- :mod:`slam.synthetic`: loop trajectories, revisit images and pose-graph problems with known answers.
"""
