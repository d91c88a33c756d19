"""Inference: :class:`VOPredictor` (flow -> 6DoF mean and std, batched) and trajectory chaining.

All 6DoF vectors are the paper's ``(euler_x, euler_y, euler_z, t_x, t_y, t_z)`` of
``cam_j_from_cam_i`` for a flow from frame i to frame j (radians, metres, OpenCV axes), float64.
"""
from __future__ import annotations

import functools
from pathlib import Path
from typing import Sequence as Seq

import numpy as np
import torch
from tqdm import tqdm

from deepslam.flow.estimators import to_network_input
from deepslam.flow.images import to_grey
from deepslam.gen.motion import MIRROR_SIGNS
from deepslam.runtime.device import resolve_bf16
from deepslam.vo.attribution import mirror_input
from deepslam.vo.calibration import widened_std
from deepslam.vo.data.frames import frame_inverse_depth
from deepslam.vo.data.prefetch import PairInputs
from deepslam.vo.geometry.epipolar import EpipolarFitter, fuse_all
from deepslam.vo.geometry.road_image import road_image
from deepslam.vo.modelfiles.modelio import load_model
from deepslam.vo.modelfiles.models import fit_config, recorded_std_scale


class VOPredictor:
    """A trained flow -> 6DoF network, ready for batched inference.

    Args:
        model: a :class:`vo.net.PoseNet` (either pose head), or a :class:`vo.ensemble.EnsemblePoseNet` of several (put in
            eval mode here).
        name: short name shown in logs (the model file's stem).
        meta: what the model file says about its training.
        batch_size: flows per forward pass.
        bf16: run under bfloat16 autocast (None = on CUDA, or when the CPU has native bf16).
        device: torch device to run on (a ``torch.device`` or its name; default the CPU).
        channels_last: NHWC convolutions (faster on this CPU).
        centre_principal_point: move every flow so that the camera's principal point lies at the image's centre
            before the network reads it (:func:`flow.estimators.centre_principal_point`).
        mirror_average: read every flow also mirrored left-right and average the two motions (:meth:`predict`;
            for a network trained on mirrored frames, ``train --mirror-frames``).
    """

    def __init__(self, model: torch.nn.Module, name: str = "vo", meta: dict | None = None, batch_size: int = 64,
                 bf16: bool | None = None, channels_last: bool = True, device: str | torch.device = "cpu",
                 centre_principal_point: bool = False, mirror_average: bool = False):
        self.model = model.eval()
        if channels_last:
            self.model.set_channels_last(True)
        self.name = name
        self.meta = meta or {}
        self.batch_size = int(batch_size)
        self.device = torch.device(device)
        self.model = self.model.to(self.device)
        if bf16 is None:
            bf16 = resolve_bf16("auto", self.device)
        self.bf16 = bool(bf16)
        self.centre_principal_point = bool(centre_principal_point)
        """Every flow is moved so that the camera's principal point lies at the image's centre before the network
        reads it (:func:`flow.estimators.centre_principal_point`)."""
        self.mirror_average = bool(mirror_average)
        """Every flow is read as it is and mirrored left-right, the two motions averaged (:meth:`predict`)."""
        self.std_scale = recorded_std_scale(self.meta)
        """(6,) per-DoF factor on every predicted std (``deepslam calibrate``; ones when the file records none)."""

    @classmethod
    def from_file(cls, path: str | Path, **kwargs) -> "VOPredictor":
        """Load a ``model.safetensors`` (or a training ``checkpoint.safetensors``); InputError when missing or malformed."""
        model, meta = load_model(path)
        kwargs.setdefault("name", Path(path).stem)
        recorded_std_scale(meta, path)  # a malformed calibration is refused here, naming the file
        return cls(model, meta=meta, **kwargs)

    @property
    def input_size(self) -> tuple[int, int]:
        """(height, width) of the flow the network takes, pixels."""
        return self.model.cfg.input_height, self.model.cfg.input_width

    @property
    def needs_depth(self) -> bool:
        """True for a network with a depth channel: it reads the first frame's depth of every pair."""
        return bool(self.model.cfg.depth_channel)

    @torch.inference_mode()
    def predict(self, flow, intrinsics, inv_depth=None) -> tuple[np.ndarray, np.ndarray]:
        """6DoF mean and std for flows at network resolution.

        With :attr:`mirror_average`, each flow is read a second time mirrored left-right (columns reversed, u
        negated, the principal point's column mirrored; :func:`vo.attribution.mirror_input`), that motion mirrored
        back (:data:`gen.motion.MIRROR_SIGNS`), and the two means averaged: what the network reads differently in a
        scene and in its mirror image (its own lack of mirror symmetry: a street's layout it learned) cancels to first
        order; an off-centre principal point does not (it is mirrored with the camera, and its heading error with
        it). The std is the root of the two variances' mean (both readings share the flow's errors).

        Args:
            flow: (B, 2, h, w) float32 px (numpy or torch), h x w = :attr:`input_size`.
            intrinsics: (B, 4) fx, fy, cx, cy at network resolution (used by coord-channel models).
            inv_depth: (B, 1, h, w) float32 1/m of each pair's first frame (depth-channel models only).

        Returns:
            (mean6, std6): float64 (B, 6) each; std6 > 0.
        """
        flow = torch.as_tensor(np.asarray(flow, dtype=np.float32)) if not torch.is_tensor(flow) else flow.float()
        intr = torch.as_tensor(np.asarray(intrinsics, dtype=np.float32)) if not torch.is_tensor(intrinsics) else intrinsics.float()
        if flow.ndim != 4 or len(intr) != len(flow):
            raise ValueError(f"flow (B, 2, h, w) and intrinsics (B, 4) expected, got {tuple(flow.shape)}, {tuple(intr.shape)}")
        inv = None if inv_depth is None else (inv_depth.float() if torch.is_tensor(inv_depth)
                                              else torch.as_tensor(np.asarray(inv_depth, dtype=np.float32)))
        mean6, log_std6 = self._read(flow, intr, inv)
        if not (self.mirror_average and len(flow)):
            return mean6, np.exp(log_std6) * self.std_scale
        m_flow, m_intr = mirror_input(flow.cpu().numpy(), intr.cpu().numpy())
        m_inv = None if inv is None else torch.flip(inv, dims=[-1])
        m_mean6, m_log_std6 = self._read(torch.from_numpy(m_flow), torch.from_numpy(m_intr), m_inv)
        var6 = 0.5 * (np.exp(2 * log_std6) + np.exp(2 * m_log_std6))
        return 0.5 * (mean6 + m_mean6 * MIRROR_SIGNS), np.sqrt(var6) * self.std_scale

    def _read(self, flow: torch.Tensor, intr: torch.Tensor, inv: torch.Tensor | None) -> tuple[np.ndarray, np.ndarray]:
        """The network's (mean6, log_std6), float64 (B, 6), of flows (B, 2, h, w), in batches of :attr:`batch_size`."""
        means, log_stds = [], []
        for s in range(0, len(flow), self.batch_size):
            sl = slice(s, s + self.batch_size)
            with torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=self.bf16):
                m, ls = self.model(flow[sl].to(self.device), intr[sl].to(self.device),
                                   None if inv is None else inv[sl].to(self.device))
            means.append(m.double().cpu())
            log_stds.append(ls.double().cpu())
        if not means:
            return np.zeros((0, 6)), np.zeros((0, 6))
        return torch.cat(means).numpy(), torch.cat(log_stds).numpy()

    def prepare(self, flow_full: np.ndarray, camera) -> tuple[np.ndarray, np.ndarray]:
        """Full-resolution flow (H, W, 2) -> network input ((2, h, w) px, (4,) intrinsics)."""
        h, w = self.input_size
        return to_network_input(flow_full, camera, w, h, self.model.cfg.unknown_flow, self.centre_principal_point)

    def predict_pairs(self, seq, pairs: Seq[tuple[int, int]], flow_estimator, progress: bool = True,
                      chunk: int = 64, inputs=None, epipolar=None, geometry=None,
                      fits_out: list | None = None, road_out: list | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Flow for every pair (i, j) of ``seq`` by ``flow_estimator`` (and, for a depth-channel
        network, frame i's depth: :func:`vo.data.frames.frame_inverse_depth`), then 6DoF of cam_j_from_cam_i.

        The flows are computed in a background thread (:class:`vo.data.prefetch.PairInputs`) while the
        network runs on the previous chunk. ``inputs``: a :class:`vo.data.prefetch.PairInputs` the caller
        started earlier for the same pairs (``deepslam vo`` starts it before loading torch); one made
        for another input size, or without the epipolar fit asked for, is closed and replaced.

        ``epipolar``: a :class:`vo.geometry.epipolar.EpipolarConfig` to take each pair's rotation and direction of
        travel from the essential matrix of its full-resolution flow and only the distance from the
        network (``deepslam vo --pose epipolar``; pairs the fit cannot serve keep the network's motion);
        ``(fit, used)`` of each pair, in the order of the pairs, is appended to ``fits_out`` when given
        (``used``: :func:`vo.geometry.epipolar.fuse` took the fit), and the sequence's
        :class:`vo.geometry.epipolar.RoadDistances` to ``road_out`` (with a road height in ``epipolar``: the images of
        pairs whose flow shows no usable road are read again for :func:`vo.geometry.road_image.image_road_q`). The
        std stays the network's.

        ``geometry``: an :class:`vo.geometry.epipolar.EpipolarConfig` (the road's distance, as ``vo``'s default reads
        it) whose reading of each pair widens the std per DoF by its difference from the network's
        (:func:`vo.calibration.widened_std`, ``vo --std-from-geometry``); the motions stay the network's without
        ``epipolar``, the fit's with it (which must then be ``geometry`` itself: ValueError otherwise).

        Returns (mean6, std6): float64 (P, 6) in the order of ``pairs``.
        """
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        h, w = self.input_size
        unknown = self.model.cfg.unknown_flow
        fit_cfg = fit_config(epipolar, geometry)
        fit = None
        if fit_cfg is not None:
            fit = EpipolarFitter(fit_cfg)
        centre = self.centre_principal_point
        if inputs is not None and ((inputs.height, inputs.width, inputs.unknown, inputs.centre) != (h, w, unknown, centre)
                                   or not np.array_equal(inputs.pairs, pairs) or inputs.full_flow_fn != fit):
            inputs.close()
            inputs = None
        if inputs is None:
            inputs = PairInputs(seq, pairs, flow_estimator, w, h, unknown=unknown, full_flow_fn=fit, centre=centre)
        means, stds = [], []
        with inputs, tqdm(total=len(pairs), desc=f"vo {self.name}", unit="pair", disable=not progress,
                          leave=False) as bar:
            it = iter(inputs)
            for s in range(0, len(pairs), chunk):
                part = pairs[s:s + chunk]
                flows = np.zeros((len(part), 2, h, w), np.float32)
                intr = np.zeros((len(part), 4), np.float32)
                inv = np.zeros((len(part), 1, h, w), np.float32) if self.needs_depth else None
                for k, (i, _) in enumerate(part):
                    flows[k], intr[k] = next(it)
                    if inv is not None:
                        inv[k] = frame_inverse_depth(seq, int(i), w, h)
                    bar.update(1)
                m, sd = self.predict(flows, intr, inv)
                means.append(m)
                stds.append(sd)
        if not means:
            return np.zeros((0, 6)), np.zeros((0, 6))
        mean6, std6 = np.concatenate(means), np.concatenate(stds)
        network6 = mean6.copy()  # the network's own readings, before the fit replaces any
        if fit is not None:
            side = inputs.side
            # consecutive pairs share a frame: each is decoded and prepared once (two threads read the two
            # halves of the pairs, each holding its last two frames)
            frame = functools.lru_cache(maxsize=4)(lambda i: road_image(to_grey(seq.image(i)), seq.camera))
            mean6, used = fuse_all(mean6, side, fit_cfg, seq.camera,
                                   lambda p: (frame(int(pairs[p, 0])), frame(int(pairs[p, 1]))),
                                   road_out, chained=bool(np.array_equal(pairs[1:, 0], pairs[:-1, 1])))
            if fits_out is not None:
                fits_out.extend(zip(side, used.tolist()))
        if geometry is not None:
            std6 = widened_std(std6, network6 - mean6)
            if epipolar is None:  # the net pose: the geometry only widened the std
                mean6 = network6
        return mean6, std6

    def as_odometry(self, flow_estimator, progress: bool = True, epipolar=None, geometry=None) -> "PredictorOdometry":
        """This predictor with a flow estimator, as the SLAM pipeline's odometry (name, predict(seq, pairs));
        ``epipolar``, ``geometry``: see :meth:`predict_pairs`."""
        return PredictorOdometry(self, flow_estimator, progress, epipolar, geometry)


class PredictorOdometry:
    """Adapter: ``predict(seq, pairs) -> (mean6, std6)`` with a fixed flow estimator."""

    def __init__(self, predictor: VOPredictor, flow_estimator, progress: bool = True, epipolar=None, geometry=None):
        self.predictor = predictor
        self.flow_estimator = flow_estimator
        self.progress = progress
        self.epipolar = epipolar
        self.geometry = geometry
        self.name = (f"{predictor.name}+{getattr(flow_estimator, 'name', 'flow')}" + ("+epipolar" if epipolar else "")
                     + ("+std-from-geometry" if geometry else ""))

    def predict(self, seq, pairs):
        return self.predictor.predict_pairs(seq, pairs, self.flow_estimator, progress=self.progress,
                                            epipolar=self.epipolar, geometry=self.geometry)

    def predict_verified(self, seq, pairs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`predict` and, per pair, whether its flow fits one rigid motion (:attr:`vo.geometry.epipolar.EpipolarFit.rigid`):
        ((P, 6), (P, 6) float64, (P,) bool). Without an epipolar fit nothing is checked (all True)."""
        if self.epipolar is None and self.geometry is None:
            mean6, std6 = self.predict(seq, pairs)
            return mean6, std6, np.ones(len(mean6), bool)
        fits: list = []
        mean6, std6 = self.predictor.predict_pairs(seq, pairs, self.flow_estimator, progress=self.progress,
                                                   epipolar=self.epipolar, geometry=self.geometry, fits_out=fits)
        return mean6, std6, np.array([fit.rigid for fit, _ in fits], bool)
