"""Rigid transforms as homogeneous 4x4 float64 matrices, batched over leading axes.

Names carry frames: ``a_from_b`` maps points in frame b to frame a, and transforms compose right to
left, ``cam1_from_cam0 = cam1_from_world @ world_from_cam0``. Every function takes arrays of shape
(..., 4, 4) and broadcasts over the leading axes.

The paper's 6DoF vector is ``(euler_x, euler_y, euler_z, t_x, t_y, t_z)`` with R = Rz @ Ry @ Rx
(radians, metres): :func:`to_euler6` / :func:`from_euler6`.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

# scipy's extrinsic "xyz" is R = Rz(c) @ Ry(b) @ Rx(a): the paper's order.
_EULER_SEQ = "xyz"


def identity(batch_shape: tuple[int, ...] = ()) -> np.ndarray:
    """Identity transforms, shape (*batch_shape, 4, 4), float64."""
    out = np.zeros((*batch_shape, 4, 4))
    out[..., [0, 1, 2, 3], [0, 1, 2, 3]] = 1.0
    return out


def from_rt(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Build ``a_from_b`` from its rotation (..., 3, 3) and translation (..., 3) (metres, frame a)."""
    rotation = np.asarray(rotation, dtype=np.float64)
    translation = np.asarray(translation, dtype=np.float64)
    batch = np.broadcast_shapes(rotation.shape[:-2], translation.shape[:-1])
    out = identity(batch)
    out[..., :3, :3] = rotation
    out[..., :3, 3] = translation
    return out


def inverse(a_from_b: np.ndarray) -> np.ndarray:
    """``b_from_a`` from ``a_from_b`` using R^T, -R^T t (exact for rigid transforms)."""
    a_from_b = np.asarray(a_from_b, dtype=np.float64)
    r_t = np.swapaxes(a_from_b[..., :3, :3], -1, -2)
    return from_rt(r_t, -np.einsum("...ij,...j->...i", r_t, a_from_b[..., :3, 3]))


def compose(*transforms: np.ndarray) -> np.ndarray:
    """``compose(a_from_b, b_from_c, ...)`` = ``a_from_b @ b_from_c @ ...``."""
    out = np.asarray(transforms[0], dtype=np.float64)
    for t in transforms[1:]:
        out = out @ np.asarray(t, dtype=np.float64)
    return out


def transform_points(a_from_b: np.ndarray, p_b: np.ndarray) -> np.ndarray:
    """Map points (..., N, 3) in frame b to frame a; ``a_from_b`` is (4, 4) or (..., 4, 4)."""
    a_from_b = np.asarray(a_from_b)
    return np.einsum("...ij,...nj->...ni", a_from_b[..., :3, :3], p_b) + a_from_b[..., None, :3, 3]


def from_quat_wxyz(quat_wxyz: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """From a unit quaternion (w, x, y, z) (MuJoCo, EuRoC order) and a translation."""
    q = np.asarray(quat_wxyz, dtype=np.float64)
    return from_quat_xyzw(np.concatenate([q[..., 1:], q[..., :1]], axis=-1), translation)


def from_quat_xyzw(quat_xyzw: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """From a unit quaternion (x, y, z, w) (scipy, TUM order) and a translation."""
    q = np.asarray(quat_xyzw, dtype=np.float64)
    rot = Rotation.from_quat(q.reshape(-1, 4)).as_matrix().reshape(*q.shape[:-1], 3, 3)
    return from_rt(rot, translation)


def to_quat_xyzw(a_from_b: np.ndarray) -> np.ndarray:
    """Unit quaternion (..., 4) in (x, y, z, w) order with w >= 0."""
    a_from_b = np.asarray(a_from_b, dtype=np.float64)
    q = Rotation.from_matrix(a_from_b[..., :3, :3].reshape(-1, 3, 3)).as_quat(canonical=True)
    return q.reshape(*a_from_b.shape[:-2], 4)


def to_quat_wxyz(a_from_b: np.ndarray) -> np.ndarray:
    """Unit quaternion (..., 4) in (w, x, y, z) order with w >= 0."""
    q = to_quat_xyzw(a_from_b)
    return np.concatenate([q[..., 3:], q[..., :3]], axis=-1)


def from_euler6(vec6: np.ndarray) -> np.ndarray:
    """From the paper's vector (..., 6): euler x, y, z (rad, R = Rz Ry Rx) then t x, y, z (m)."""
    v = np.asarray(vec6, dtype=np.float64)
    rot = Rotation.from_euler(_EULER_SEQ, v[..., :3].reshape(-1, 3)).as_matrix()
    return from_rt(rot.reshape(*v.shape[:-1], 3, 3), v[..., 3:])


def to_euler6(a_from_b: np.ndarray) -> np.ndarray:
    """The paper's vector (..., 6): euler x, y, z (rad, R = Rz Ry Rx) then t x, y, z (m)."""
    a_from_b = np.asarray(a_from_b, dtype=np.float64)
    eul = Rotation.from_matrix(a_from_b[..., :3, :3].reshape(-1, 3, 3)).as_euler(_EULER_SEQ)
    return np.concatenate([eul.reshape(*a_from_b.shape[:-2], 3), a_from_b[..., :3, 3]], axis=-1)


def rotation_angle(a_from_b: np.ndarray) -> np.ndarray:
    """Rotation angle (..., ) in radians, in [0, pi]; atan2 form, accurate near 0 and pi."""
    r = np.asarray(a_from_b, dtype=np.float64)[..., :3, :3]
    cos = (np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0
    vee = np.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], axis=-1)
    return np.arctan2(np.linalg.norm(vee, axis=-1) / 2.0, cos)


def orthonormality_error(rotation: np.ndarray) -> np.ndarray:
    """max |R^T R - I| and |det R - 1| per matrix, shape (...,)."""
    r = np.asarray(rotation, dtype=np.float64)
    rtr = np.swapaxes(r, -1, -2) @ r
    err = np.abs(rtr - np.eye(3)).max(axis=(-2, -1))
    return np.maximum(err, np.abs(np.linalg.det(r) - 1.0))


def project_to_so3(rotation: np.ndarray) -> np.ndarray:
    """Nearest rotation (Frobenius) via SVD, for matrices that drifted by rounding."""
    u, _, vt = np.linalg.svd(np.asarray(rotation, dtype=np.float64))
    d = np.sign(np.linalg.det(u @ vt))
    u[..., :, 2] *= d[..., None]
    return u @ vt


def relative(world_from_a: np.ndarray, world_from_b: np.ndarray) -> np.ndarray:
    """``a_from_b = inverse(world_from_a) @ world_from_b`` (the motion from a to b seen in a)."""
    return inverse(world_from_a) @ np.asarray(world_from_b, dtype=np.float64)


def chain(cam_next_from_cam: np.ndarray) -> np.ndarray:
    """Poses ``world_from_cam`` (N + 1, 4, 4) float64 with world = the first camera, from N relative
    motions ``cam_{k+1}_from_cam_k`` (N, 4, 4): ``world_from_cam_{k+1} = world_from_cam_k @ inv(cam_{k+1}_from_cam_k)``."""
    rel = np.asarray(cam_next_from_cam, dtype=np.float64)
    out = np.empty((len(rel) + 1, 4, 4))
    out[0] = np.eye(4)
    inv = inverse(rel)
    for k in range(len(rel)):
        out[k + 1] = out[k] @ inv[k]
    return out


def chain_euler6(mean6: np.ndarray) -> np.ndarray:
    """:func:`chain` of paper vectors (N, 6) -> world_from_cam (N + 1, 4, 4)."""
    return chain(from_euler6(np.asarray(mean6, dtype=np.float64).reshape(-1, 6)))
