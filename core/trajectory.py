"""A camera trajectory: timestamps and world_from_cam poses, plus stride motions and interpolation."""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from deepslam.core import se3
from deepslam.core.errors import InputError


@dataclasses.dataclass(frozen=True, eq=False)
class Trajectory:
    """N poses of one camera.

    Attributes:
        world_from_cam: (N, 4, 4) float64, OpenCV camera axes, metres.
        timestamps_s: (N,) float64 seconds, strictly increasing; None where the source has no times
            (a KITTI poses file alone), in which case frames are matched by index.
    """

    world_from_cam: np.ndarray
    timestamps_s: np.ndarray | None = None

    def __post_init__(self) -> None:
        poses = np.asarray(self.world_from_cam, dtype=np.float64)
        if poses.ndim != 3 or poses.shape[1:] != (4, 4):
            raise ValueError(f"world_from_cam must be (N, 4, 4), got {poses.shape}")
        object.__setattr__(self, "world_from_cam", poses)
        if self.timestamps_s is not None:
            t = np.asarray(self.timestamps_s, dtype=np.float64)
            if t.shape != (len(poses),):
                raise ValueError(f"timestamps_s must be ({len(poses)},), got {t.shape}")
            object.__setattr__(self, "timestamps_s", t)

    def __len__(self) -> int:
        return len(self.world_from_cam)

    def __getitem__(self, idx) -> "Trajectory":
        idx = np.arange(len(self))[idx]
        return Trajectory(self.world_from_cam[idx], None if self.timestamps_s is None else self.timestamps_s[idx])

    @property
    def positions(self) -> np.ndarray:
        """(N, 3) camera centres in the world frame, metres."""
        return self.world_from_cam[:, :3, 3]

    def path_length_m(self) -> float:
        return float(np.linalg.norm(np.diff(self.positions, axis=0), axis=1).sum())

    def cumulative_distance_m(self) -> np.ndarray:
        """(N,) distance travelled from the first pose, metres (KITTI devkit's trajectoryDistances)."""
        d = np.linalg.norm(np.diff(self.positions, axis=0), axis=1)
        return np.concatenate([[0.0], np.cumsum(d)])

    def relative_motions(self, stride: int = 1) -> np.ndarray:
        """(N - stride, 4, 4) ``cam_{i+stride}_from_cam_i``: the motion that moves points seen in
        frame i into frame i+stride (the target of flow-based odometry)."""
        if stride < 1:
            raise ValueError("stride must be >= 1")
        return se3.inverse(self.world_from_cam[stride:]) @ self.world_from_cam[:-stride]

    def transformed(self, new_world_from_world: np.ndarray) -> "Trajectory":
        return Trajectory(np.asarray(new_world_from_world) @ self.world_from_cam, self.timestamps_s)

    def relative_to_first(self) -> "Trajectory":
        """The same trajectory expressed in its first camera's frame (first pose = identity)."""
        return self.transformed(se3.inverse(self.world_from_cam[0]))

    def interpolate(self, timestamps_s: np.ndarray) -> "Trajectory":
        """Poses at the given times: slerp for rotation, linear for translation.

        Raises ValueError when a time lies outside [t_0, t_{N-1}].
        """
        if self.timestamps_s is None:
            raise ValueError("trajectory has no timestamps")
        t = np.asarray(timestamps_s, dtype=np.float64)
        t0, t1 = self.timestamps_s[0], self.timestamps_s[-1]
        if len(t) and (t.min() < t0 - 1e-9 or t.max() > t1 + 1e-9):
            raise ValueError(f"times [{t.min():.6f}, {t.max():.6f}] outside the trajectory's [{t0:.6f}, {t1:.6f}]")
        t = np.clip(t, t0, t1)
        rot = Slerp(self.timestamps_s, Rotation.from_matrix(self.world_from_cam[:, :3, :3]))(t).as_matrix()
        pos = np.stack([np.interp(t, self.timestamps_s, self.positions[:, k]) for k in range(3)], axis=-1)
        return Trajectory(se3.from_rt(rot, pos), t)


def check_finite_poses(world_from_cam: np.ndarray, source: str) -> None:
    """InputError naming ``source`` (the odometry, the pose graph) when a chained or optimised trajectory
    (N, 4, 4) float64 holds a non-finite pose: checked before the trajectory is written, so that no file
    holds NaN or inf whatever produced it."""
    bad = ~np.isfinite(np.asarray(world_from_cam, dtype=np.float64)).reshape(len(world_from_cam), -1).all(axis=1)
    if bad.any():
        raise InputError(None, f"{source} gave a trajectory that is not finite from pose {int(np.flatnonzero(bad)[0])} "
                               "on (overflowing or NaN motions); nothing was written")


def associate(a: Trajectory, b: Trajectory, max_diff_s: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Match poses of two trajectories by timestamp, as evo does.

    For each time of ``a`` the nearest time of ``b`` within ``max_diff_s`` is taken, and each pose of
    ``b`` is used at most once (greedy on increasing difference). Returns index arrays (ia, ib) of
    equal length in increasing order of ``a``'s time.
    """
    if a.timestamps_s is None or b.timestamps_s is None:
        raise ValueError("both trajectories need timestamps to be associated")
    ta, tb = a.timestamps_s, b.timestamps_s
    order = np.argsort(tb)
    tb_sorted = tb[order]
    pos = np.clip(np.searchsorted(tb_sorted, ta), 1, max(len(tb_sorted) - 1, 1))
    left = pos - 1
    right = np.minimum(pos, len(tb_sorted) - 1)
    pick = np.where(np.abs(tb_sorted[left] - ta) <= np.abs(tb_sorted[right] - ta), left, right)
    diff = np.abs(tb_sorted[pick] - ta)
    ia = np.flatnonzero(diff <= max_diff_s)
    ib = order[pick[ia]]
    # one-to-one: keep the closest a for each b
    keep = {}
    for i, j in zip(ia, ib):
        if j not in keep or diff[i] < diff[keep[j]]:
            keep[j] = i
    pairs = sorted((i, j) for j, i in keep.items())
    if not pairs:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    ia, ib = map(np.array, zip(*pairs))
    return ia, ib


def revisit_pairs(world_from_cam: np.ndarray, min_gap_frames: int, max_distance_m: float,
                  max_angle_deg: float, nearest_only: bool = False, min_angle_deg: float = 0.0) -> np.ndarray:
    """The frame pairs that see the same place again: (P, 2) int64 (i, j), i < j, ordered by i then j.

    Args:
        world_from_cam: (N, 4, 4) float poses (metres), one per frame.
        min_gap_frames: j - i at least this (a revisit, not the next frames).
        max_distance_m: camera centres at most this far apart, metres.
        max_angle_deg: relative rotation at most this, degrees.
        nearest_only: keep, for each later frame j, only the pair whose camera centres are nearest (at most one
            pair per j, then ordered by j): a camera standing still for n frames gives about n pairs, not n^2 / 2.
        min_angle_deg: relative rotation at least this, degrees (e.g. 160 with ``max_angle_deg`` 180: the same
            road driven the opposite way).
    """
    poses = np.asarray(world_from_cam, np.float64)
    pos = poses[:, :3, 3]
    gap = max(int(min_gap_frames), 1)
    pairs = []
    for j in range(gap, len(poses)):
        i = np.arange(j - gap + 1)
        dist = np.linalg.norm(pos[j] - pos[i], axis=1)
        near = dist <= max_distance_m
        if not near.any():
            continue
        i, dist = i[near], dist[near]
        angle = np.rad2deg(se3.rotation_angle(se3.relative(poses[j][None], poses[i])))
        ok = (angle <= max_angle_deg) & (angle >= min_angle_deg)
        if not ok.any():
            continue
        if nearest_only:
            pairs.append((int(i[np.argmin(np.where(ok, dist, np.inf))]), j))
        else:
            pairs += [(int(k), j) for k in i[ok]]
    pairs = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    return pairs if nearest_only else pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
