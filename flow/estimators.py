"""Optical flow between two frames behind one interface (DIS, the simulator's exact flow), resizing a flow to a
network's input, and flow error measures.

Every estimator returns ``flow`` float32 (H, W, 2) at the images' full resolution with
``flow[v, u] = (du, dv)`` in pixels from the first image to the second (u = column, pixel centres at
integers), the project's convention.

Estimators are made by name from a registry (:func:`deepslam.flow.registry.make`, ``register``, ``names``):

- ``dis``: OpenCV's DIS optical flow (Kroeger et al., 2016), the default; preset ``ultrafast``,
  ``fast`` or ``medium`` (the default: on KITTI 06 its median end-point error against flow from
  stereo depth + ground-truth motion is 1.3 px vs 2.4 px for ``ultrafast``, at ~10x the time).
- ``learned``: the compact PWC-style network the harness trains on its own renders
  (:mod:`flow.net`, ``deepslam train-flow``; shipped as ``models/flow_learned.safetensors``).
- ``learned-dis``: that network's flow as the start of DIS medium, which refines it
  (:class:`flow.net.LearnedDISFlow`).
- ``gt``: the simulator's exact flow. Consecutive frames read the flow the sequence stores
  (``flow/NNNNNN.npy``, frame i to i+1: exact for static, moving and deforming surfaces). Pairs
  further apart (loop pairs) are computed from geometry (:func:`exact_pair_flow`: frame i's depth, the
  ground-truth motion and the rigid movers' poses), since chaining a hundred per-frame flows through
  occlusions and pixels that leave the view gives nonsense; without depth they are chained
  (:func:`chain_flows`).

A learned estimator (RAFT, PWC-Net...) is added by registering a factory that returns an object with
``name``, ``estimate(img0, img1)`` and, if it can do better than reading the two images,
``pair_flow(seq, i, j)``. One that offers ``replica()`` (an estimator with the same settings, giving
the same flows, that another thread may use while this one runs) lets :class:`vo.data.prefetch.PairInputs`
compute several pairs at once (DIS does: each replica single-threaded, one per core).
"""
from __future__ import annotations

import copy
import dataclasses
import math
from typing import Protocol

import cv2
import numpy as np

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.core.errors import InputError
from deepslam.core.ours import read_instance_poses
from deepslam.flow.images import GreyCache, texture_strength, to_grey

DIS_PRESETS = ("ultrafast", "fast", "medium")
"""Presets of OpenCV's DIS flow, fastest first."""


class FlowEstimator(Protocol):
    """What every flow estimator provides."""

    name: str

    def estimate(self, img0: np.ndarray, img1: np.ndarray) -> np.ndarray:
        """Flow (H, W, 2) float32 px from ``img0`` to ``img1`` (uint8 (H, W) grey or (H, W, 3) RGB)."""
        ...

    def pair_flow(self, seq, i: int, j: int) -> np.ndarray:
        """Flow (H, W, 2) float32 px from frame i to frame j of a :class:`core.sequence.Sequence`."""
        ...


def forward_backward_error(forward: np.ndarray, backward: np.ndarray) -> np.ndarray:
    """|forward(x) + backward(x + forward(x))| per pixel: (H, W) float32 pixels, 0 for a consistent pair,
    NaN where the forward flow is unknown or lands outside the image (the round trip is
    :func:`chain_flows` of the two: the backward flow sampled bilinearly at the landing point).

    forward: (H, W, 2) float32 (du, dv) px from image 0 to image 1; backward: the same from 1 to 0.
    """
    h, w = forward.shape[:2]
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    x1, y1 = xs + forward[..., 0], ys + forward[..., 1]
    err = np.linalg.norm(chain_flows([forward, backward]), axis=-1)
    err[~((x1 >= 0) & (x1 <= w - 1) & (y1 >= 0) & (y1 <= h - 1))] = np.nan  # also where the flow is NaN
    return err


def _non_negative(value, what: str) -> float:
    """``value`` as a finite float >= 0; InputError naming ``what`` otherwise."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = math.nan
    if not (math.isfinite(x) and x >= 0):
        raise InputError(None, f"{what} must be a finite number >= 0, got {value!r}")
    return x


class DISFlow:
    """OpenCV DIS optical flow on grey images.

    Args:
        preset: ``ultrafast`` | ``fast`` | ``medium`` (cv2.DISOPTICAL_FLOW_PRESET_*); medium by default.
        min_texture: where the first image's :func:`texture_strength` is below this ((grey levels / px)^2),
            the flow is NaN (unknown) instead of DIS's guess; 0 (default) keeps every pixel. On a real
            camera's textureless walls DIS's flow is its regularizer's and the sensor noise's, not the
            scene's motion (TUM fr3/teddy: median error 2.8 px on the least textured quarter of the pixels,
            0.4 px on the most textured; README, RGB-D odometry), and a network that reads every pixel
            reads that as motion. The name says the threshold (``dis-medium-tex0.5``), so a model's
            training record names the flow it learned from.
        fb_max_px: forward-backward check: DIS also runs from the second image to the first, and the flow
            is NaN (unknown) where the backward flow at the pixel the forward flow lands on does not bring
            it back to within this many pixels (occlusions, pixels leaving the view, matches DIS got
            wrong), or lands outside the image; 0 (default): no check. Twice DIS's time. In the name:
            ``dis-medium-tex0.5-fb0.5``.
        max_width: DIS runs on images wider than this many pixels downscaled to this width (aspect kept;
            cv2.INTER_AREA), and its flow comes back resized to the images' size with its vectors scaled to
            match (:func:`resize_flow`), so callers see a full-size flow either way; 0 (default): the images
            as given. About (max_width / width)^2 of DIS's time: an odometry that reads 96x320 flow does not
            read the detail of a 1241-wide frame. A limit in pixels, not a factor, so a model trained on
            640-wide renders and 1241-wide KITTI frames sees DIS at the same working size in training and on
            a KITTI camera. The forward-backward check runs at the reduced size, with ``fb_max_px`` in
            full-size pixels; the texture threshold on the full-size first image. In the name:
            ``dis-medium-w640``.
        patch_stride: pixels between the patches DIS matches at each level (``setPatchStride``); 0 (default):
            the preset's (medium: 3, with 8-pixel patches). Fewer patches, less time: on 1226x370 KITTI frames
            on one AVX2 core, medium takes 62 ms a pair, with stride 4 46 ms, 5 39 ms (2026-12-04), and its
            flow moves by a median 0.07 px at stride 4. At most the preset's patch size. In the name:
            ``dis-medium-s4``.
    """

    def __init__(self, preset: str = "medium", min_texture: float = 0.0, fb_max_px: float = 0.0,
                 max_width: int = 0, patch_stride: int = 0):
        if preset not in DIS_PRESETS:
            raise InputError(None, f"unknown DIS preset {preset!r} (one of {', '.join(DIS_PRESETS)})")
        min_texture = _non_negative(min_texture, "DIS min_texture (--dis-min-texture)")
        fb_max_px = _non_negative(fb_max_px, "DIS fb_max_px (--dis-fb-check)")
        width_limit = _non_negative(max_width, "DIS max_width (--dis-max-width)")
        if width_limit != int(width_limit) or 0 < width_limit < 16:
            raise InputError(None, f"DIS max_width (--dis-max-width) must be 0 (no limit) or a whole number of "
                                   f"pixels >= 16, got {max_width!r}")
        self._preset_code = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
                             "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}[preset]
        stride = _non_negative(patch_stride, "DIS patch_stride (--dis-patch-stride)")
        patch = cv2.DISOpticalFlow_create(self._preset_code).getPatchSize()
        if stride != int(stride) or stride > patch:
            raise InputError(None, f"DIS patch_stride (--dis-patch-stride) must be 0 (the preset's) or a whole number "
                                   f"of pixels from 1 to the patch size {patch}, got {patch_stride!r}")
        self.patch_stride = int(stride)
        self.preset = preset
        self.max_width = int(width_limit)
        self.min_texture = min_texture
        self.fb_max_px = fb_max_px
        self.name = (f"dis-{preset}" + (f"-tex{min_texture:g}" if min_texture > 0 else "")
                     + (f"-fb{fb_max_px:g}" if fb_max_px > 0 else "") + (f"-w{self.max_width}" if self.max_width else "")
                     + (f"-s{self.patch_stride}" if self.patch_stride else ""))
        self._dis = self._new_dis()
        self._grey = GreyCache()

    def _new_dis(self):
        """An OpenCV DIS with this estimator's preset and patch stride."""
        dis = cv2.DISOpticalFlow_create(self._preset_code)
        if self.patch_stride:
            dis.setPatchStride(self.patch_stride)
        return dis

    def estimate(self, img0: np.ndarray, img1: np.ndarray, start: np.ndarray | None = None) -> np.ndarray:
        """Flow (H, W, 2) float32 px from ``img0`` to ``img1`` (uint8 (H, W) grey or (H, W, 3) RGB); ``start``:
        an optional (H, W, 2) float32 px flow DIS starts from at its coarsest level (the forward flow only)."""
        g0, g1 = to_grey(img0), to_grey(img1)
        if g0.shape != g1.shape:
            raise ValueError(f"images differ in size: {g0.shape} vs {g1.shape}")
        h, w = g0.shape
        a, b = g0, g1
        if self.max_width and w > self.max_width:
            size = (self.max_width, max(8, round(h * self.max_width / w)))
            a = cv2.resize(g0, size, interpolation=cv2.INTER_AREA)
            b = cv2.resize(g1, size, interpolation=cv2.INTER_AREA)
            if start is not None:
                start = np.ascontiguousarray(resize_flow(start, *size))
        flow = np.ascontiguousarray(self._dis.calc(a, b, start), dtype=np.float32)
        if self.fb_max_px > 0:
            back = np.ascontiguousarray(self._dis.calc(b, a, None), dtype=np.float32)
            fb_max = self.fb_max_px * a.shape[1] / w  # full-size pixels at the size DIS ran at
            flow[~(forward_backward_error(flow, back) <= fb_max)] = np.nan
        if a is not g0:
            flow = resize_flow(flow, w, h, unknown="nan")
        if self.min_texture > 0:
            flow[texture_strength(g0) < self.min_texture] = np.nan
        return flow

    def pair_flow(self, seq, i: int, j: int) -> np.ndarray:
        return self.estimate(self._grey(seq, i), self._grey(seq, j))

    def replica(self) -> "DISFlow":
        """An estimator with the same settings (the same flows, bit for bit) for another thread: a shallow copy
        (a subclass stays its class) with an OpenCV DIS of its own; it shares this one's decoded images
        (:class:`GreyCache`)."""
        twin = copy.copy(self)
        twin._dis = self._new_dis()
        return twin


class GroundTruthFlow:
    """The simulator's exact flow: stored for consecutive frames (our format: frame i to i+1); pairs
    further apart from geometry (:func:`exact_pair_flow`), or chained where the sequence has no depth."""

    name = "gt"

    def estimate(self, img0: np.ndarray, img1: np.ndarray) -> np.ndarray:
        raise InputError(None, "ground-truth flow needs a sequence with flow (use pair_flow), not two images")

    def pair_flow(self, seq, i: int, j: int) -> np.ndarray:
        if seq.flow_paths is None:
            raise InputError(seq.root, "sequence has no ground-truth flow (flow/ folder); use --flow dis")
        if j <= i:
            raise InputError(seq.root, f"ground-truth flow goes forward only, asked for {i} -> {j}")
        if j > i + 1 and seq.depth_paths is not None and seq.gt is not None:
            return exact_pair_flow(seq, i, j)
        flows = []
        for k in range(i, j):
            f = seq.flow(k)
            if f is None:
                raise InputError(seq.root, f"no ground-truth flow for frame {k}")
            flows.append(np.nan_to_num(f, nan=0.0, posinf=0.0, neginf=0.0))
        return chain_flows(flows)


def exact_pair_flow(seq, i: int, j: int) -> np.ndarray:
    """Exact flow (H, W, 2) float32 px from frame i to frame j of a rendered sequence, from geometry.

    Each pixel of frame i with depth is unprojected, moved by ``cam_j_from_cam_i`` (ground truth) or,
    on a rigid mover (instance id in ``mask/`` with a pose in both frame records), by that body's own
    motion ``cam_j_from_world @ world_from_body_j @ body_i_from_world @ world_from_cam_i``, and
    projected into frame j. Pixels without depth (sky) are points at infinity (rotation-only flow),
    and points that leave the view keep their flow, as in the training data
    (:func:`deepslam.gen.flow.synthesize_flow`) and as a dense estimator reports them. Deforming surfaces are
    moved with the static scene (their own motion between distant frames is not recorded).
    """
    # deferred: torch (and gen.flow, which imports it) take seconds to load, and the header-only readers
    # (vo.data.prefetch) import this module before torch is needed
    import torch

    from deepslam.gen.flow import synthesize_flow

    cam = seq.camera
    depth = seq.depth(i)
    world_from_cam = seq.gt.world_from_cam
    cam_j_from_cam_i = se3.relative(world_from_cam[j], world_from_cam[i])
    depths, motions = [depth], [cam_j_from_cam_i]
    mask = seq.mask(i) if seq.mask_paths is not None else None
    if mask is not None and mask.any() and seq.kind == "ours":
        poses_i, poses_j = read_instance_poses(seq.root, i), read_instance_poses(seq.root, j)
        static = depth.copy()
        for k in np.unique(mask[mask > 0]):
            if int(k) in poses_i and int(k) in poses_j:
                on = mask == k
                depths.append(np.where(on, depth, 0).astype(np.float32))
                motions.append(se3.inverse(world_from_cam[j]) @ poses_j[int(k)] @ se3.inverse(poses_i[int(k)])
                               @ world_from_cam[i])
                static[on] = np.nan  # not part of the static scene (and no point at infinity either)
        depths[0] = static
    k4 = np.tile(cam.intrinsics(), (len(depths), 1))
    flow, _ = synthesize_flow(torch.from_numpy(np.stack(depths).astype(np.float32)), k4, np.stack(motions),
                              missing_depth="infinity")
    # the static scene (NaN on the movers), plus each mover's own synthesis where its depth is
    out = flow[0] * torch.from_numpy(np.isfinite(depths[0]))[None]
    for b in range(1, len(depths)):
        out += flow[b] * torch.from_numpy(depths[b] > 0)[None]
    return out.permute(1, 2, 0).numpy().copy()


def chain_flows(flows: list[np.ndarray]) -> np.ndarray:
    """Compose flows f_{0->1}, f_{1->2}, ... into f_{0->n} (all (H, W, 2) float32 px).

    ``f_{0->2}(x) = f_{0->1}(x) + f_{1->2}(x + f_{0->1}(x))`` with bilinear sampling; where the
    intermediate position falls outside the image the nearest border value is used (exact for
    rigid scenes only where nothing is occluded in between).
    """
    out = np.asarray(flows[0], dtype=np.float32).copy()
    if len(flows) == 1:
        return out
    h, w = out.shape[:2]
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    for f in flows[1:]:
        f = np.asarray(f, dtype=np.float32)
        sampled = cv2.remap(f, u + out[..., 0], v + out[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        out += sampled
    return out


UNKNOWN_FLOW = ("zero", "nan")
"""How :func:`resize_flow` treats pixels whose flow is unknown (NaN or inf: DIS's textureless pixels,
no depth): ``zero`` = as flow 0, averaged in with their known neighbours (what every network trained
before the validity channel reads); ``nan`` = left out of the average, and NaN where a network pixel
covers no known pixel at all (what a :attr:`vo.net.NetConfig.valid_channel` network reads)."""


def unknown_flow(valid_channel: bool) -> str:
    """How a network reads unknown flow (:data:`UNKNOWN_FLOW`): ``nan`` with a validity channel, else
    ``zero`` (:attr:`vo.net.NetConfig.unknown_flow`; the header-only reader in :mod:`vo.data.prefetch`)."""
    return "nan" if valid_channel else "zero"


def check_unknown(unknown: str) -> str:
    """``unknown`` if it is one of :data:`UNKNOWN_FLOW`, else ValueError."""
    if unknown not in UNKNOWN_FLOW:
        raise ValueError(f"unknown must be one of {UNKNOWN_FLOW}, got {unknown!r}")
    return unknown


def resize_flow(flow: np.ndarray, width: int, height: int, unknown: str = "zero") -> np.ndarray:
    """A flow (H, W, 2) float32 px resampled to (height, width, 2) with its values rescaled.

    The pixel grid maps as the camera does (:meth:`core.camera.PinholeCamera.scaled`,
    ``u' = (u + 0.5) sx - 0.5``), so a displacement du becomes ``du * sx`` with ``sx = width / W``
    (and dv ``* sy``). Downsampling averages over the source area (cv2.INTER_AREA), upsampling is
    bilinear. Non-finite values (unknown flow) are, by ``unknown`` (:data:`UNKNOWN_FLOW`): ``zero``,
    replaced by 0 first; ``nan``, left out of each output pixel's average (weighted by the known
    pixels' share of it), and the output is NaN where no known pixel contributes. A flow with no
    unknown pixel resizes to the same values either way.
    """
    check_unknown(unknown)
    flow = np.asarray(flow, dtype=np.float32)
    if flow.ndim != 3 or flow.shape[2] != 2:
        raise ValueError(f"flow must be (H, W, 2), got {flow.shape}")
    known = None
    if not np.isfinite(flow).all():  # the check is 50x cheaper than nan_to_num on a finite flow
        if unknown == "nan":
            known = np.isfinite(flow).all(axis=2).astype(np.float32)
        flow = np.nan_to_num(flow, nan=0.0, posinf=0.0, neginf=0.0)
        if known is not None:
            flow *= known[..., None]  # a pixel with one finite component is unknown as a whole
    h0, w0 = flow.shape[:2]
    if (h0, w0) == (height, width):
        out = flow.copy()
        if known is not None:
            out[known == 0] = np.nan
        return out
    interp = cv2.INTER_AREA if (width <= w0 and height <= h0) else cv2.INTER_LINEAR
    out = cv2.resize(flow, (width, height), interpolation=interp)
    if known is not None:
        share = cv2.resize(known, (width, height), interpolation=interp)
        empty = share <= 1e-6
        out /= np.where(empty, 1.0, share)[..., None]
        out[empty] = np.nan
    out[..., 0] *= width / w0
    out[..., 1] *= height / h0
    return out


def centre_principal_point(flow: np.ndarray, camera: PinholeCamera) -> tuple[np.ndarray, PinholeCamera]:
    """A flow as the same camera would see it with its principal point at the image's centre.

    The pixel grid is shifted by ``(cx - (W - 1) / 2, cy - (H - 1) / 2)``: the flow at output pixel (u, v) is the
    input's at (u + dx, v + dy), bilinear (the focal length is kept, so every value is unchanged, only moved). A
    column or row the shift brings in from outside the image repeats the edge; NaN (unknown) stays unknown and
    spreads at most one pixel. A network that never sees the intrinsics (the paper's) learns the focus of expansion's
    place in the image from its training cameras, which the simulator renders centred; KITTI 04-10's principal
    point lies 10.6 px left of its centre (0.86 deg), which such a network reads as heading and yaw.

    Args:
        flow: (H, W, 2) float32 px at the camera's resolution, NaN where unknown.
        camera: :class:`core.camera.PinholeCamera` of the images (H x W).

    Returns:
        ``(flow, camera)``: float32 (H, W, 2) px, and the camera with ``cx = (W - 1) / 2``, ``cy = (H - 1) / 2``
        (the input itself, not a copy, when the principal point is already within 1e-3 px of the centre).
    """
    dx, dy = camera.principal_point_offset
    centred = dataclasses.replace(camera, cx=(camera.width - 1) / 2.0, cy=(camera.height - 1) / 2.0)
    if abs(dx) < 1e-3 and abs(dy) < 1e-3:
        return flow, centred
    shift = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy]])
    out = cv2.warpAffine(np.asarray(flow, dtype=np.float32), shift, (camera.width, camera.height),
                         flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
    return out, centred


def to_network_input(flow: np.ndarray, camera, width: int, height: int,
                     unknown: str = "zero", centre: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Full-resolution flow -> the network's input.

    Args:
        flow: (H, W, 2) float32 px at the camera's resolution; NaN where unknown.
        camera: :class:`core.camera.PinholeCamera` of the images (H x W).
        width, height: the network's input size.
        unknown: how unknown flow is resized (:func:`resize_flow`; ``nan`` for a network with a
            validity channel, which then holds NaN where nothing is known).
        centre: first move the principal point to the image's centre (:func:`centre_principal_point`).

    Returns:
        ``(flow_chw, intrinsics)``: float32 (2, height, width) px at network resolution, and float32
        (4,) ``(fx, fy, cx, cy)`` of the camera (centred with ``centre``) scaled to that resolution.
    """
    if flow.shape[:2] != (camera.height, camera.width):
        raise ValueError(f"flow is {flow.shape[:2]} but the camera is {camera.height}x{camera.width}")
    if centre:
        flow, camera = centre_principal_point(flow, camera)
    small = resize_flow(flow, width, height, unknown)
    cam = camera.scaled(width, height)
    return (np.ascontiguousarray(small.transpose(2, 0, 1)),
            cam.intrinsics(np.float32))
