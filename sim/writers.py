"""Write rendered sequences to disk: our format, KITTI odometry, EuRoC ASL and TUM RGB-D layouts.

Every file is written atomically (temporary name + rename). A frame counts as done only once its
record is written, which happens after all its files; so a killed render leaves no frame that
looks complete, and ``resume=True`` renders exactly the missing frames (renders are deterministic,
so the result is byte-identical to an uninterrupted run). The sequence-level files a reader needs
(poses, times, data.csv) are written last, by ``finish``.

Layouts (``N`` frames, ``NNNNNN`` = zero-padded frame index):

- ours (``core.ours``): ``<out>/{sequence.json, rgb/, rgb_right/, depth/, flow/, mask/, frames/, poses.txt, times.txt}``.
- kitti: ``<out>/sequences/<NN>/{image_0, image_1 (grey PNG), image_2, image_3 (colour PNG), calib.txt,
  times.txt, depth/NNNNNN.npy, flow/NNNNNN.npy, mask/NNNNNN.png, deepslam.json}`` and
  ``<out>/poses/<NN>.txt`` (cam0 world_from_cam, 12 numbers per line). calib.txt has P0..P3
  (``K [I | t]``; P1 and P3 with ``-fx * B`` in their [0, 3]; the colour pair sits where the grey
  pair is) and Tr (identity: there is no lidar).
- euroc: ``<out>/mav0/{cam0, cam1}/{data.csv, data/<ns>.png (grey), sensor.yaml}``,
  ``<out>/mav0/cam0/{depth, flow, mask}/NNNNNN.*`` numbered by data.csv row,
  ``<out>/mav0/state_groundtruth_estimate0/{data.csv, sensor.yaml}`` (world_from_body at 200 Hz
  plus every frame time, from 0.1 s before the first frame to 0.1 s after the last, ASL columns), ``<out>/mav0/body.yaml``, ``<out>/deepslam.json``. The
  body (IMU) frame is not the camera's: ``T_BS`` of cam0 is a fixed realistic rotation and offset
  (EuRoC's own cam0 extrinsics, orthonormalised), cam1 sits at +B along cam0's x axis.

- tum: ``<out>/{rgb/NNNNNN.png (colour), depth/NNNNNN.png (uint16, 5000 per metre, 0 = no depth or beyond
  13.107 m), rgb.txt, depth.txt, groundtruth.txt (TUM: t tx ty tz qx qy qz qw, world_from_cam, OpenCV
  axes), intrinsics.txt (fx fy cx cy), flow/, flow_backward/, occlusion/, mask/, deepslam.json}``, as
  TUM RGB-D publishes its sequences (left camera only; times 0-based, 6 decimals).

Flow files are ``NNNNNN.npy`` (float32 HxWx2); ``config.render.flow_formats`` adds Middlebury
``NNNNNN.flo`` and KITTI 2015 ``NNNNNN.png`` beside them (:mod:`core.flowio`), in every layout.
The last frame has no flow file (there is no next frame in the sequence).
"""
from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from deepslam.core import atomic, flowio, se3
from deepslam.core.dynamic import dynamic_fraction
from deepslam.core.errors import InputError
from deepslam.core.integrity import file_digests, record_files_match
from deepslam.core.lock import output_lock
from deepslam.core.ours import OursWriter
from deepslam.core.trajectory import Trajectory
from deepslam.core.trajio import write_trajectory
from deepslam.core.tum import DEPTH_SCALE as TUM_DEPTH_SCALE
from deepslam.sim.config import FORMATS, SimConfig
from deepslam.sim.simulator import Simulator

EUROC_T0_NS = 1_600_000_000_000_000_000
"""Timestamp (ns) of frame 0 in EuRoC exports (absolute, like the real data's)."""
EUROC_GT_RATE_HZ = 200.0

# EuRoC V1 cam0's body_from_cam (T_BS), made exactly orthonormal.
_EUROC_T_BS = np.array([[0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975],
                        [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768],
                        [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949],
                        [0.0, 0.0, 0.0, 1.0]])
BODY_FROM_CAM0 = se3.from_rt(se3.project_to_so3(_EUROC_T_BS[:3, :3]), _EUROC_T_BS[:3, 3])


def _name(i: int) -> str:
    return f"{i:06d}"


DYNAMIC_FRACTION_FILE = "dynamic_fraction.txt"
"""Per-frame share of the image (0-1) covered by dynamic surfaces (mask > 0: movers, waving flags),
one line per frame, written beside the images' times in every layout."""


def _write_dynamic_fraction(path: Path, values) -> None:
    atomic.write_text(path, "".join(f"{float(v):.6f}\n" for v in values))


def render_record(out: Path, fmt: str, sequence: str = "00") -> Path:
    """The file that marks ``out`` as a render in layout ``fmt`` (each sink writes it before any frame)."""
    if fmt == "ours":
        return out / "sequence.json"
    if fmt == "kitti":
        return out / "sequences" / sequence / "deepslam.json"
    return out / "deepslam.json"


def check_output_folder(out: Path, resume: bool, record: Path | None = None) -> None:
    """InputError (before anything is written) when ``out`` cannot be used: a file, a non-empty
    folder without ``resume``, a non-empty folder without the render ``record`` with ``resume`` (it
    never was a render: nothing in it is deleted or written), or a place where nothing can be created."""
    if out.exists() and not out.is_dir():
        raise InputError(out, "output exists and is not a folder")
    if out.is_dir():
        if any(out.iterdir()) and not resume:
            raise InputError(out, "output folder exists and is not empty (use --resume to finish an interrupted render)")
        if resume and record is not None and any(out.iterdir()) and not record.is_file():
            raise InputError(out, f"cannot resume: not an interrupted render ({record.relative_to(out)} is missing); "
                                  "nothing in it was changed")
        if not os.access(out, os.W_OK | os.X_OK):
            raise InputError(out, "output folder is not writable")
        return
    parent = out.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(out, f"cannot create the output folder ({parent} is not writable)")


def put_flow(put, folder: Path, name: str, flow: np.ndarray, formats) -> None:
    """Write one flow field (H, W, 2) float32 (du, dv) px into ``folder`` in each of ``formats``
    (:data:`sim.config.FLOW_FORMATS`): ``<name>.npy``, ``<name>.flo`` (Middlebury), ``<name>.png`` (KITTI
    2015); ``put(write, path, data)`` writes and lists a file."""
    flow = flow.astype(np.float32)
    if "npy" in formats:
        put(atomic.write_npy, folder / f"{name}.npy", flow)
    if "flo" in formats:
        put(flowio.write_flo, folder / f"{name}.flo", flow)
    if "png" in formats:
        put(flowio.write_kitti_flow_png, folder / f"{name}.png", flow)


def tum_depth_png(depth_z: np.ndarray) -> np.ndarray:
    """(H, W) uint16 TUM depth image of ``depth_z`` (H, W) float32 metres: round(depth * 5000), 0 where
    the depth is 0 (no surface) or beyond what 16 bits hold (65535 / 5000 = 13.107 m)."""
    q = np.round(depth_z.astype(np.float64) * TUM_DEPTH_SCALE)
    q[~np.isfinite(q) | (q < 0) | (q > 65535)] = 0
    return q.astype(np.uint16)


class _Sink:
    """Base: per-frame records in a hidden folder mark frames done (kitti, euroc)."""

    def __init__(self, sim, root: Path, config: SimConfig, resume: bool):
        self.sim = sim
        self.root = root
        self.config = config
        self.n = sim.num_frames

    def _records(self) -> Path:
        raise NotImplementedError

    def done(self, i: int) -> bool:
        """Frame i's record exists and every file it lists still has the bytes written (a damaged or
        replaced file makes the frame be rendered again on --resume)."""
        return record_files_match(self._records() / f"{_name(i)}.json", self.root)

    def _put_ground_truth(self, put, folder: Path, i: int, frame, depth_png: bool = False) -> None:
        """Frame i's ground truth beside the images, numbered like them: ``depth/`` (the sensor's when
        simulated, the exact one then in ``depth_exact/``; ``depth_png``: a TUM 16-bit PNG instead of
        the .npy), ``flow/`` and ``occlusion/`` (none for the last frame), ``flow_backward/`` (the flow
        in every format of ``config.render.flow_formats``), ``mask/``; ``put(write, path, data)``
        writes and lists a file."""
        n = _name(i)
        last = i >= self.n - 1
        sensor = frame.depth_sensor is not None
        depth = (frame.depth_sensor if sensor else frame.depth_z).astype(np.float32)
        if depth_png:
            put(atomic.write_png, folder / "depth" / f"{n}.png", tum_depth_png(depth))
        else:
            put(atomic.write_npy, folder / "depth" / f"{n}.npy", depth)
        if sensor:
            put(atomic.write_npy, folder / "depth_exact" / f"{n}.npy", frame.depth_z.astype(np.float32))
        formats = ("npy", *self.config.render.flow_formats)
        if frame.flow is not None and not last:
            put_flow(put, folder / "flow", n, frame.flow, formats)
        if frame.occlusion is not None and not last:
            put(atomic.write_png, folder / "occlusion" / f"{n}.png", frame.occlusion.astype(np.uint8) * 255)
        if frame.flow_backward is not None:
            put_flow(put, folder / "flow_backward", n, frame.flow_backward, formats)
        put(atomic.write_png, folder / "mask" / f"{n}.png", frame.mask.astype(np.uint16))
        if frame.row_poses is not None:
            put(atomic.write_npy, folder / "row_poses" / f"{n}.npy", frame.row_poses.astype(np.float64))

    def _mark(self, i: int, frame, written: list[Path]) -> None:
        atomic.write_json(self._records() / f"{_name(i)}.json",
                          {"index": i, "timestamp_s": frame.timestamp_s, "world_from_cam": frame.world_from_cam.tolist(),
                           "dynamic_fraction": dynamic_fraction(frame.mask), "files": file_digests(written, self.root)})

    def _meta(self, fmt: str, complete: bool, extra: dict) -> dict:
        sim = self.sim
        return {"format": fmt, "generator": "deepslam render", "complete": complete, "num_frames": self.n,
                "rate_hz": sim.rate_hz, "camera": sim.camera.to_dict(), "stereo_baseline_m": sim.baseline_m,
                "backend": sim.backend_name, "scene": sim.scene.name, "trajectory": getattr(sim.motion, "name", None),
                "config": sim.resolved_config.to_dict(), "instances": _instances(sim), **_rolling_shutter_meta(sim), **extra}

    def _check_resume(self, meta_path: Path, meta: dict) -> bool:
        """True when the folder holds a finished render of the same config."""
        if not meta_path.is_file():
            return False
        try:
            old = json.loads(meta_path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise InputError(meta_path, f"cannot read ({e})") from None
        new = json.loads(json.dumps(meta, default=atomic._json_default))
        keys = [k for k in set(old) | set(new) if k != "complete" and old.get(k) != new.get(k)]
        if keys:
            raise InputError(meta_path, f"cannot resume: settings differ from the interrupted run ({', '.join(sorted(keys))})")
        return bool(old.get("complete"))


def _rolling_shutter_meta(sim) -> dict:
    """``{"rolling_shutter": {...}}`` for the sequence metadata under a rolling shutter, else {}."""
    offsets = sim.row_time_offsets_s
    if offsets is None:
        return {}
    rcfg = sim.config.render
    return {"rolling_shutter": {"readout_ms": rcfg.rolling_shutter_ms, "bands": len(sim.shutter_bands),
                                "row_time_offsets_s": [float(x) for x in offsets],
                                "row_poses": "row_poses/NNNNNN.npy: (H, 4, 4) float64 world_from_cam of each row"}}


def _instances(sim) -> dict:
    return {str(b.instance_id): {"name": b.name, "kind": b.kind} for b in sim.scene.bodies if b.instance_id}


class OursSink:
    def __init__(self, sim, root: Path, config: SimConfig, resume: bool):
        self.sim = sim
        self.config = config
        self.n = sim.num_frames
        header = {"num_frames": self.n, "rate_hz": sim.rate_hz, "camera": sim.camera.to_dict(),
                  "stereo_baseline_m": sim.baseline_m, "scene": sim.scene.name,
                  "trajectory": getattr(sim.motion, "name", None), "seed": config.scene.seed, "backend": sim.backend_name,
                  "config": sim.resolved_config.to_dict(), "instances": _instances(sim),
                  "has": {"rgb_right": bool(sim.baseline_m), "depth": True, "flow": bool(config.render.flow), "mask": True,
                          "flow_backward": bool(config.render.flow), "occlusion": bool(config.render.flow),
                          "row_poses": config.render.rolling_shutter,
                          "depth_exact": config.render.depth_noise is not None},
                  **_rolling_shutter_meta(sim)}
        self.complete = False
        if resume and (root / "sequence.json").is_file():
            try:
                self.complete = bool(json.loads((root / "sequence.json").read_text()).get("complete"))
            except (OSError, json.JSONDecodeError):
                self.complete = False
        self.writer = OursWriter(root, header, resume=resume)
        # a finished render keeps its records: it counts as complete only while every frame still hashes
        # to its record (a damaged or missing frame is rendered again and the sequence files rewritten)
        self.complete = self.complete and all(self.writer.done(i) for i in range(self.n))
        if self.complete:
            self.writer.header["complete"] = True
            atomic.write_json(root / "sequence.json", self.writer.header)
        self.path = root

    def done(self, i: int) -> bool:
        return self.complete or self.writer.done(i)

    def write(self, i: int, frame) -> None:
        flow = frame.flow if i < self.n - 1 else None
        sensor = frame.depth_sensor is not None
        # flow in the other formats first (the .npy files are the writer's); the record lists them too
        more: list[Path] = []
        formats = tuple(f for f in self.config.render.flow_formats if f != "npy")

        def put(write, path: Path, data) -> None:
            write(path, data)
            more.append(path)

        if formats:
            if flow is not None:
                put_flow(put, self.path / "flow", _name(i), flow, formats)
            if frame.flow_backward is not None:
                put_flow(put, self.path / "flow_backward", _name(i), frame.flow_backward, formats)
        self.writer.write_frame(i, frame.timestamp_s, frame.world_from_cam, frame.rgb,
                                frame.depth_sensor if sensor else frame.depth_z, flow, frame.mask,
                                frame.rgb_right, extra={"instance_poses": {str(k): v.tolist() for k, v in frame.instance_poses.items()},
                                                        "dynamic_fraction": dynamic_fraction(frame.mask)},
                                flow_backward=frame.flow_backward, occlusion=frame.occlusion if i < self.n - 1 else None,
                                depth_exact=frame.depth_z if sensor else None, row_poses=frame.row_poses,
                                more_files=more)

    def finish(self) -> None:
        if not self.complete:
            recs = [json.loads((self.path / "frames" / f"{_name(i)}.json").read_text()) for i in range(self.n)]
            _write_dynamic_fraction(self.path / DYNAMIC_FRACTION_FILE, [r["dynamic_fraction"] for r in recs])
            self.writer.finish()


class KittiSink(_Sink):
    def __init__(self, sim, root: Path, config: SimConfig, resume: bool, sequence: str = "00"):
        super().__init__(sim, root, config, resume)
        self.seq = root / "sequences" / sequence
        self.poses_path = root / "poses" / f"{sequence}.txt"
        self.meta_path = self.seq / "deepslam.json"
        self.meta = self._meta("kitti", False, {"sequence": sequence})
        self.complete = self._check_resume(self.meta_path, self.meta) if resume else False
        self.path = self.seq
        if not self.complete:
            atomic.write_json(self.meta_path, self.meta)
            cam, b = sim.camera, sim.baseline_m or 0.0
            p0 = np.hstack([cam.k, np.zeros((3, 1))])
            p1 = p0.copy()
            p1[0, 3] = -cam.fx * b
            tr = np.hstack([np.eye(3), np.zeros((3, 1))])
            lines = [f"{name}: " + " ".join(f"{x:.16e}" for x in p.ravel()) for name, p in
                     (("P0", p0), ("P1", p1), ("P2", p0), ("P3", p1), ("Tr", tr))]
            atomic.write_text(self.seq / "calib.txt", "\n".join(lines) + "\n")

    def _records(self) -> Path:
        return self.seq / ".deepslam_frames"

    def done(self, i: int) -> bool:
        return self.complete or super().done(i)

    def write(self, i: int, frame) -> None:
        n = _name(i)
        written = []

        def put(write, path: Path, data) -> None:
            write(path, data)
            written.append(path)

        put(atomic.write_png, self.seq / "image_0" / f"{n}.png", cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY))
        put(atomic.write_png, self.seq / "image_2" / f"{n}.png", frame.rgb)
        if frame.rgb_right is not None:
            put(atomic.write_png, self.seq / "image_1" / f"{n}.png", cv2.cvtColor(frame.rgb_right, cv2.COLOR_RGB2GRAY))
            put(atomic.write_png, self.seq / "image_3" / f"{n}.png", frame.rgb_right)
        self._put_ground_truth(put, self.seq, i, frame)
        self._mark(i, frame, written)

    def finish(self) -> None:
        if self.complete:
            return
        recs = [json.loads((self._records() / f"{_name(i)}.json").read_text()) for i in range(self.n)]
        poses = np.array([r["world_from_cam"] for r in recs])[:, :3, :].reshape(self.n, 12)
        atomic.write_text(self.poses_path, "".join(" ".join(f"{x:.12e}" for x in row) + "\n" for row in poses))
        atomic.write_text(self.seq / "times.txt", "".join(f"{r['timestamp_s']:.9e}\n" for r in recs))
        _write_dynamic_fraction(self.seq / DYNAMIC_FRACTION_FILE, [r["dynamic_fraction"] for r in recs])
        self.meta["complete"] = True
        atomic.write_json(self.meta_path, self.meta)
        shutil.rmtree(self._records(), ignore_errors=True)


def _sensor_yaml(comment: str, body_from_cam: np.ndarray, rate_hz: float, cam, distortion=None) -> str:
    d = body_from_cam.ravel()
    rows = [", ".join(repr(float(x)) for x in d[k:k + 4]) for k in range(0, 16, 4)]
    data = (",\n         ".join(rows))
    rate = int(rate_hz) if float(rate_hz).is_integer() else rate_hz
    return ("%YAML:1.0\n# General sensor definitions.\nsensor_type: camera\n"
            f"comment: {comment}\n\n# Sensor extrinsics wrt. the body-frame.\nT_BS:\n  cols: 4\n  rows: 4\n"
            f"  data: [{data}]\n\n# Camera specific definitions.\nrate_hz: {rate}\n"
            f"resolution: [{cam.width}, {cam.height}]\ncamera_model: pinhole\n"
            f"intrinsics: [{cam.fx!r}, {cam.fy!r}, {cam.cx!r}, {cam.cy!r}] #fu, fv, cu, cv\n"
            "distortion_model: radial-tangential\n"
            f"distortion_coefficients: [{', '.join(repr(float(x)) for x in (distortion or (0.0, 0.0, 0.0, 0.0)))}]\n"
            + ("" if distortion is None else
               "# deepslam: the pinhole camera the images undistort to; depth/, flow/, mask/ are in it\n"
               f"undistorted_intrinsics: [{cam.fx!r}, {cam.fy!r}, {cam.cx!r}, {cam.cy!r}]\n"))


_GT_HEADER = ("#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], "
              "v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], "
              "b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]")
_GT_SENSOR_YAML = ("%YAML:1.0\n# General sensor definitions.\nsensor_type: visual-inertial\n"
                   "comment: Ground truth of the deepslam simulator (exact): world_from_body.\n\n"
                   "# Sensor extrinsics wrt. the body-frame. This is the transformation of the\n"
                   "# tracking prima to the body frame.\nT_BS:\n  cols: 4\n  rows: 4\n"
                   "  data: [1.0, 0.0, 0.0, 0.0,\n         0.0, 1.0, 0.0, 0.0,\n         0.0, 0.0, 1.0, 0.0,\n"
                   "         0.0, 0.0, 0.0, 1.0]\n")


class EurocSink(_Sink):
    def __init__(self, sim, root: Path, config: SimConfig, resume: bool):
        super().__init__(sim, root, config, resume)
        self.mav = root / "mav0"
        self.meta_path = root / "deepslam.json"
        self.meta = self._meta("euroc", False, {"t0_ns": EUROC_T0_NS, "body_from_cam0": BODY_FROM_CAM0.tolist()})
        self.complete = self._check_resume(self.meta_path, self.meta) if resume else False
        self.path = root
        if not self.complete:
            atomic.write_json(self.meta_path, self.meta)
            cam, b = sim.camera, sim.baseline_m
            dist = config.render.distortion if config.render.distorted else None
            what = "rectified, radial-tangential distortion" if dist else "rectified pinhole"
            atomic.write_text(self.mav / "cam0" / "sensor.yaml",
                              _sensor_yaml(f"deepslam simulator cam0 ({what})", BODY_FROM_CAM0, sim.rate_hz, cam, dist))
            if b:
                body_from_cam1 = BODY_FROM_CAM0 @ se3.from_rt(np.eye(3), [b, 0.0, 0.0])
                atomic.write_text(self.mav / "cam1" / "sensor.yaml",
                                  _sensor_yaml(f"deepslam simulator cam1 ({what})", body_from_cam1, sim.rate_hz, cam, dist))
            atomic.write_text(self.mav / "body.yaml", "%YAML:1.0\ncomment: deepslam simulated body (camera rig)\n")
            atomic.write_text(self.mav / "state_groundtruth_estimate0" / "sensor.yaml", _GT_SENSOR_YAML)

    def _records(self) -> Path:
        return self.root / ".deepslam_frames"

    def done(self, i: int) -> bool:
        return self.complete or super().done(i)

    def ns(self, i: int) -> int:
        return EUROC_T0_NS + int(round(i * 1e9 / self.sim.rate_hz))

    def write(self, i: int, frame) -> None:
        ns = self.ns(i)
        written = []

        def put(write, path: Path, data) -> None:
            write(path, data)
            written.append(path)

        put(atomic.write_png, self.mav / "cam0" / "data" / f"{ns}.png", cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY))
        if frame.rgb_right is not None:
            put(atomic.write_png, self.mav / "cam1" / "data" / f"{ns}.png", cv2.cvtColor(frame.rgb_right, cv2.COLOR_RGB2GRAY))
        self._put_ground_truth(put, self.mav / "cam0", i, frame)
        self._mark(i, frame, written)

    def finish(self) -> None:
        if self.complete:
            return
        recs = [json.loads((self._records() / f"{_name(i)}.json").read_text()) for i in range(self.n)]
        _write_dynamic_fraction(self.mav / "cam0" / DYNAMIC_FRACTION_FILE, [r["dynamic_fraction"] for r in recs])
        rows = "".join(f"{self.ns(i)},{self.ns(i)}.png\n" for i in range(self.n))
        atomic.write_text(self.mav / "cam0" / "data.csv", "#timestamp [ns],filename\n" + rows)
        if self.sim.baseline_m:
            atomic.write_text(self.mav / "cam1" / "data.csv", "#timestamp [ns],filename\n" + rows)
        # ground truth: 200 Hz plus every frame time, from 0.1 s before the first frame to 0.1 s after
        # the last (readers convert ns to s in different ways), world_from_body = world_from_cam0 @ cam0_from_body
        t_end_ns = self.ns(self.n - 1) - EUROC_T0_NS
        step = int(round(1e9 / EUROC_GT_RATE_HZ))
        grid = np.arange(-20 * step, t_end_ns + 20 * step + 1, step, dtype=np.int64)
        frames = np.array([self.ns(i) - EUROC_T0_NS for i in range(self.n)], np.int64)
        ns = np.unique(np.concatenate([grid, frames]))
        t = ns.astype(np.float64) * 1e-9
        cam0_from_body = se3.inverse(BODY_FROM_CAM0)
        world_from_body = self.sim.motion.world_from_cam(t) @ cam0_from_body
        h = 1e-4
        vel = ((self.sim.motion.world_from_cam(t + h) @ cam0_from_body)[:, :3, 3]
               - (self.sim.motion.world_from_cam(t - h) @ cam0_from_body)[:, :3, 3]) / (2 * h)
        q = se3.to_quat_wxyz(world_from_body)
        lines = [_GT_HEADER]
        for k in range(len(ns)):
            vals = [*world_from_body[k, :3, 3], *q[k], *vel[k], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
            lines.append(f"{EUROC_T0_NS + int(ns[k])}," + ",".join(repr(float(x)) for x in vals))
        atomic.write_text(self.mav / "state_groundtruth_estimate0" / "data.csv", "\n".join(lines) + "\n")
        self.meta["complete"] = True
        atomic.write_json(self.meta_path, self.meta)
        shutil.rmtree(self._records(), ignore_errors=True)


class TumSink(_Sink):
    """TUM RGB-D layout (read back by :func:`core.tum.read_tum`): colour and depth PNGs, the file lists,
    ``groundtruth.txt`` and ``intrinsics.txt``; the left camera only."""

    def __init__(self, sim, root: Path, config: SimConfig, resume: bool):
        super().__init__(sim, root, config, resume)
        self.meta_path = root / "deepslam.json"
        self.meta = self._meta("tum", False, {"depth_scale": TUM_DEPTH_SCALE})
        self.complete = self._check_resume(self.meta_path, self.meta) if resume else False
        self.path = root
        if not self.complete:
            atomic.write_json(self.meta_path, self.meta)
            cam = sim.camera
            atomic.write_text(root / "intrinsics.txt", f"{cam.fx!r} {cam.fy!r} {cam.cx!r} {cam.cy!r}\n")

    def _records(self) -> Path:
        return self.root / ".deepslam_frames"

    def done(self, i: int) -> bool:
        return self.complete or super().done(i)

    def write(self, i: int, frame) -> None:
        written = []

        def put(write, path: Path, data) -> None:
            write(path, data)
            written.append(path)

        put(atomic.write_png, self.root / "rgb" / f"{_name(i)}.png", frame.rgb)
        self._put_ground_truth(put, self.root, i, frame, depth_png=True)
        self._mark(i, frame, written)

    def finish(self) -> None:
        if self.complete:
            return
        recs = [json.loads((self._records() / f"{_name(i)}.json").read_text()) for i in range(self.n)]
        # the times as the lists print them (TUM's 6 decimals), so ground truth sits exactly at the frames
        stamps = [f"{r['timestamp_s']:.6f}" for r in recs]
        for name, what, ext in (("rgb", "color images", "png"), ("depth", "depth maps", "png")):
            lines = [f"# {what}", "# file: 'deepslam render'", "# timestamp filename"]
            lines += [f"{t} {name}/{_name(i)}.{ext}" for i, t in enumerate(stamps)]
            atomic.write_text(self.root / f"{name}.txt", "\n".join(lines) + "\n")
        traj = Trajectory(np.array([r["world_from_cam"] for r in recs], np.float64), np.array([float(t) for t in stamps]))
        write_trajectory(self.root / "groundtruth.txt", traj, "tum")
        _write_dynamic_fraction(self.root / DYNAMIC_FRACTION_FILE, [r["dynamic_fraction"] for r in recs])
        self.meta["complete"] = True
        atomic.write_json(self.meta_path, self.meta)
        shutil.rmtree(self._records(), ignore_errors=True)


def _remove_stale_temporaries(root: Path) -> None:
    """Delete the temporary files (core.atomic: ``.<stem>.<random>.tmp<suffix>``) that a killed
    writer left behind; they are never complete files."""
    pattern = re.compile(r"^\..+\.[A-Za-z0-9_]+\.tmp(\.[A-Za-z0-9]+)?$")
    for p in root.rglob(".*"):
        if p.is_file() and pattern.match(p.name):
            p.unlink()


def render_sequence(config: SimConfig, out_dir, fmt: str = "ours", resume: bool = False, progress: bool = True,
                    sequence: str = "00", simulator=None) -> Path:
    """Render ``config`` into ``out_dir`` (see the module docstring for the layouts).

    Bad input (config values, an unusable output folder, a resume whose settings differ) raises
    core.errors.InputError before anything is written. Returns the sequence folder (what
    ``core.readers.open_sequence`` opens).
    """
    if fmt not in FORMATS:
        raise InputError(None, f"unknown format {fmt!r} (choose from {', '.join(FORMATS)})")
    if config.render.distorted and fmt != "euroc":
        raise InputError(None, f"lens distortion needs --format euroc (its sensor.yaml carries the calibration); "
                               f"{fmt} images are rectified pinhole images")
    if fmt == "kitti" and not (sequence.isdigit() and len(sequence) == 2):
        raise InputError(None, f"KITTI sequence name must be two digits, got {sequence!r}")
    config = config.validate() if simulator is None else config
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(out, "output exists and is not a folder")
    created = not out.exists()
    with output_lock(out):  # one writer: a second render into this folder is refused while this one runs
        return _render_locked(config, out, created, fmt, resume, progress, sequence, simulator)


def _render_locked(config: SimConfig, out: Path, created: bool, fmt: str, resume: bool, progress: bool,
                   sequence: str, simulator) -> Path:
    check_output_folder(out, resume, render_record(out, fmt, sequence))
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(out, f"cannot create the output folder ({e.strerror or e})") from None
    try:
        sim = simulator or Simulator(config)
    except BaseException:
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise
    try:
        # the sinks refuse a resume whose settings differ before they write anything: only then are a
        # killed run's temporary files removed
        if fmt == "ours":
            sink = OursSink(sim, out, config, resume)
        elif fmt == "kitti":
            sink = KittiSink(sim, out, config, resume, sequence)
        elif fmt == "tum":
            sink = TumSink(sim, out, config, resume)
        else:
            sink = EurocSink(sim, out, config, resume)
        if resume:
            _remove_stale_temporaries(out)
        todo = [i for i in range(sim.num_frames) if not sink.done(i)]
        for i in tqdm(todo, desc=f"render {sim.scene.name}", unit="frame", disable=not progress, dynamic_ncols=True):
            sink.write(i, sim.frame(i, flow=config.render.flow and i < sim.num_frames - 1))
        sink.finish()
        return sink.path
    finally:
        if simulator is None:
            sim.close()


def read_dynamic_fractions(path) -> list[float]:
    """The per-frame dynamic fractions a render wrote into sequence folder ``path`` (share of the image on
    dynamic surfaces, 0-1), one per frame; empty where it wrote none. EuRoC layout: beside cam0."""
    path = Path(path)
    for f in (path / DYNAMIC_FRACTION_FILE, path / "mav0" / "cam0" / DYNAMIC_FRACTION_FILE):
        if f.is_file():
            return [float(line) for line in f.read_text().split()]
    return []
