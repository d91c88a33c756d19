"""The procedural textures carry enough non-repetitive structure for DIS optical flow and SIFT."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from deepslam.scenes import SceneConfig
from deepslam.sim import RenderConfig, SimConfig, Simulator, TrajectoryConfig


@pytest.mark.parametrize("scene,ppm,width,frame", [("street", 12, 620, 60), ("room", 60, 376, 60)])
def test_dis_flow_and_sift_agree_with_ground_truth(scene, ppm, width, frame):
    cfg = SimConfig(SceneConfig(name=scene, seed=0, texture_px_per_m=ppm), TrajectoryConfig(frames=100),
                    RenderConfig(width=width, stereo_baseline_m=0))
    with Simulator(cfg) as sim:
        f0, f1 = sim.frame(frame), sim.frame(frame + 1, flow=False)
    g0, g1 = (cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY) for f in (f0, f1))
    h, w = g0.shape
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    tu, tv = u + f0.flow[..., 0], v + f0.flow[..., 1]
    valid = (tu >= 0) & (tu < w - 1) & (tv >= 0) & (tv < h - 1) & (f0.depth_z > 0)
    assert np.median(np.linalg.norm(f0.flow[valid], axis=-1)) > 3.0   # real motion between the frames
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM).calc(g0, g1, None)
    epe = np.linalg.norm(dis - f0.flow, axis=-1)[valid]
    assert np.median(epe) < 0.5 and epe.mean() < 1.5, (np.median(epe), epe.mean())
    sift = cv2.SIFT_create(2000)
    k0, d0 = sift.detectAndCompute(g0, None)
    k1, d1 = sift.detectAndCompute(g1, None)
    good = [a for a, b in cv2.BFMatcher().knnMatch(d0, d1, k=2) if a.distance < 0.75 * b.distance]
    assert len(k0) > 200 and len(good) > 100, (len(k0), len(good))
    p0 = np.array([k0[m.queryIdx].pt for m in good], np.float32)
    p1 = np.array([k1[m.trainIdx].pt for m in good])
    gt = cv2.remap(f0.flow, p0[:, 0], p0[:, 1], cv2.INTER_LINEAR).reshape(-1, 2)
    consistent = np.linalg.norm(p0 + gt - p1, axis=1) < 2.0
    assert consistent.mean() > 0.85, consistent.mean()
