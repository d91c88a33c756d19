"""deepslam core: the shared vocabulary (SE3, cameras, trajectories, sequences, metrics, plots).

Depends only on numpy, scipy, opencv and matplotlib. Nothing here imports sim, gen, vo or slam.
"""
