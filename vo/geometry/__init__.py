"""Inference geometry beside the network: rotation and direction of travel from the epipolar geometry
(:mod:`vo.geometry.epipolar`), metric scale from the road (:mod:`vo.geometry.road_flow`,
:mod:`vo.geometry.road_image`, :mod:`vo.geometry.road_sequence`; :mod:`vo.geometry.road_height` the
sim-to-real diagnostic), pose from flow and depth (:mod:`vo.geometry.posesolve`) and how a model's
translation read depends on speed (:mod:`studies.scale_sweep`)."""
