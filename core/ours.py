"""Our sequence format (written by the simulator, read here). The full spec is in README.md.

Layout of one sequence folder::

    sequence.json        header: format, version, num_frames, rate_hz, camera (PinholeCamera dict),
                         stereo_baseline_m (or null), scene, trajectory, seed, backend, config,
                         has {rgb_right, depth, flow, mask, depth_exact, ...}, complete (false while being written)
    rgb/NNNNNN.png       uint8 HxWx3 RGB, left camera
    rgb_right/NNNNNN.png uint8 HxWx3 RGB, right camera at +baseline along the camera x axis (optional)
    depth/NNNNNN.npy     float32 HxW depth_z in metres, 0 = no surface (with ``--depth-noise``: as the sensor reads it,
                         0 = no reading)
    depth_exact/NNNNNN.npy  float32 HxW exact depth_z, only with ``--depth-noise`` (``has.depth_exact``)
    flow/NNNNNN.npy      float32 HxWx2 (du, dv) pixels from frame NNNNNN to NNNNNN+1 (none for the last)
    mask/NNNNNN.png      uint16 HxW instance ids, 0 = static scene
    row_poses/NNNNNN.npy float64 Hx4x4 world_from_cam of each image row (rolling shutter only; the header's
                         ``rolling_shutter`` holds each row's capture time minus the frame time)
    frames/NNNNNN.json   per-frame record {index, timestamp_s, world_from_cam, files: {name: sha256}, ...};
                         ``--resume`` re-renders a frame whose files no longer hash to its record; written LAST for a
                         frame, so its presence means the frame is complete
    poses.txt            KITTI layout (12 numbers per line), world_from_cam, OpenCV axes; written at the end
    times.txt            one timestamp per line, seconds; written at the end

Every file is written atomically (temp file + rename), so a killed writer never leaves a file that
looks complete; ``OursWriter(resume=True)`` skips frames whose record exists.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from deepslam.core import atomic
from deepslam.core.camera import PinholeCamera
from deepslam.core.errors import InputError
from deepslam.core.integrity import file_digests, record_files_match
from deepslam.core.textio import read_json_object
from deepslam.core.sequence import Sequence
from deepslam.core.trajectory import Trajectory

FORMAT = "deepslam-sequence"
VERSION = 1


def _name(i: int) -> str:
    return f"{i:06d}"


class OursWriter:
    """Writes one sequence folder frame by frame.

    Args:
        root: output folder (created).
        header: everything for sequence.json except ``format``, ``version`` and ``complete``; must
            contain ``num_frames``, ``rate_hz`` and ``camera`` (a PinholeCamera dict).
        resume: continue an interrupted sequence; its header must match ``header``.
    """

    def __init__(self, root: str | Path, header: dict, resume: bool = False):
        self.root = Path(root)
        self.header = {"format": FORMAT, "version": VERSION, **header, "complete": False}
        self.header.setdefault("has", {"rgb_right": False, "depth": True, "flow": True, "mask": True})
        json_path = self.root / "sequence.json"
        if resume and json_path.is_file():
            old = json.loads(json_path.read_text())
            old.pop("complete", None)
            new = json.loads(json.dumps({k: v for k, v in self.header.items() if k != "complete"},
                                        default=atomic._json_default))
            if old != new:
                diff = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))
                raise InputError(json_path, f"cannot resume: settings differ from the interrupted run ({', '.join(diff)})")
        atomic.write_json(json_path, self.header)

    def done(self, i: int) -> bool:
        """Frame i's record exists and every file it lists still hashes to the digest recorded when it
        was written (a damaged frame is written again on resume)."""
        return record_files_match(self.root / "frames" / f"{_name(i)}.json", self.root)

    def write_frame(self, i: int, timestamp_s: float, world_from_cam: np.ndarray, rgb: np.ndarray,
                    depth: np.ndarray | None = None, flow: np.ndarray | None = None,
                    mask: np.ndarray | None = None, rgb_right: np.ndarray | None = None,
                    extra: dict | None = None, flow_backward: np.ndarray | None = None,
                    occlusion: np.ndarray | None = None, depth_exact: np.ndarray | None = None,
                    row_poses: np.ndarray | None = None, more_files: list[Path] | None = None) -> None:
        """Write frame i's files, then its record (which marks it complete).

        Args: rgb uint8 (H,W,3); depth float32 (H,W) depth_z m; flow float32 (H,W,2) px to frame i+1;
        mask uint16 (H,W); world_from_cam (4,4) float64 OpenCV axes; extra: JSON-able per-frame data;
        flow_backward float32 (H,W,2) px to frame i-1; occlusion bool (H,W), True = not visible in i+1;
        row_poses float64 (H,4,4) world_from_cam of each image row (rolling shutter); more_files: files
        under ``root`` the caller already wrote for this frame (e.g. flow in other formats), listed in
        the record with the rest.
        """
        n = _name(i)
        written = list(more_files or [])
        for sub, ext, data in (("rgb", "png", None if rgb is None else np.asarray(rgb, np.uint8)),
                               ("rgb_right", "png", None if rgb_right is None else np.asarray(rgb_right, np.uint8)),
                               ("depth", "npy", None if depth is None else np.asarray(depth, np.float32)),
                               ("flow", "npy", None if flow is None else np.asarray(flow, np.float32)),
                               ("mask", "png", None if mask is None else np.asarray(mask, np.uint16)),
                               ("flow_backward", "npy", None if flow_backward is None else np.asarray(flow_backward, np.float32)),
                               ("occlusion", "png", None if occlusion is None else (np.asarray(occlusion) > 0).astype(np.uint8) * 255),
                               ("depth_exact", "npy", None if depth_exact is None else np.asarray(depth_exact, np.float32)),
                               ("row_poses", "npy", None if row_poses is None else np.asarray(row_poses, np.float64))):
            if data is None:
                continue
            path = self.root / sub / f"{n}.{ext}"
            (atomic.write_png if ext == "png" else atomic.write_npy)(path, data)
            written.append(path)
        record = {"index": i, "timestamp_s": float(timestamp_s),
                  "world_from_cam": np.asarray(world_from_cam, np.float64).tolist(), **(extra or {}),
                  "files": file_digests(written, self.root)}
        atomic.write_json(self.root / "frames" / f"{n}.json", record)

    def finish(self) -> None:
        """Write poses.txt and times.txt from the frame records and mark the sequence complete."""
        n = int(self.header["num_frames"])
        missing = [i for i in range(n) if not self.done(i)]
        if missing:
            raise RuntimeError(f"{self.root}: frames {missing[:5]}... not written")
        recs = [json.loads((self.root / "frames" / f"{_name(i)}.json").read_text()) for i in range(n)]
        poses = np.array([r["world_from_cam"] for r in recs])[:, :3, :].reshape(n, 12)
        atomic.write_text(self.root / "poses.txt", "".join(" ".join(f"{x:.12e}" for x in row) + "\n" for row in poses))
        atomic.write_text(self.root / "times.txt", "".join(f"{r['timestamp_s']:.9f}\n" for r in recs))
        self.header["complete"] = True
        atomic.write_json(self.root / "sequence.json", self.header)


def _check_frame_count(root: Path, json_path: Path, n: int) -> None:
    """InputError naming the header when ``num_frames`` is not a count the folder backs: below 1, or more
    frames than ``rgb/`` holds images (counted up to ``n``, so a header claiming 10^9 frames costs a
    directory listing, not 10^9 names)."""
    if n < 1:
        raise InputError(json_path, f"num_frames must be >= 1, got {n}")
    present: set[str] = set()
    try:
        with os.scandir(root / "rgb") as it:
            for entry in it:
                if entry.name.endswith(".png"):
                    present.add(entry.name)
                    if len(present) >= n:
                        return
    except OSError:
        raise InputError(root / "rgb", "no rgb/ folder of frames") from None
    held = len(present)
    first_missing = next(i for i in range(held + 1) if f"{_name(i)}.png" not in present)  # within held + 1 names
    raise InputError(root / "rgb" / f"{_name(first_missing)}.png",
                     f"frame image is missing: {json_path.name} says num_frames {n}, rgb/ holds {held} frame images")


def read_ours(root: str | Path) -> Sequence:
    root = Path(root)
    json_path = root / "sequence.json"
    header = read_json_object(json_path, "sequence header")
    if header.get("format") != FORMAT:
        raise InputError(json_path, f"not a {FORMAT} header (format = {header.get('format')!r})")
    if not header.get("complete"):
        raise InputError(root, "sequence is incomplete (an interrupted render? rerun it with --resume)")
    try:
        n = int(header["num_frames"])
        camera = PinholeCamera.from_dict(header["camera"])
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(json_path, f"bad header field ({e})") from None
    _check_frame_count(root, json_path, n)
    has = header.get("has", {})
    names = [_name(i) for i in range(n)]
    poses = _read_kitti_poses(root / "poses.txt", n)
    times = _read_times(root / "times.txt", n)
    return Sequence(
        name=root.name, kind="ours", root=root, camera=camera, timestamps_s=times,
        image_paths=[root / "rgb" / f"{s}.png" for s in names],
        right_paths=[root / "rgb_right" / f"{s}.png" for s in names] if has.get("rgb_right") else None,
        baseline_m=header.get("stereo_baseline_m"),
        gt=Trajectory(poses, times),
        depth_paths=[root / "depth" / f"{s}.npy" for s in names] if has.get("depth") else None,
        flow_paths=([root / "flow" / f"{s}.npy" for s in names[:-1]] + [None]) if has.get("flow") else None,
        mask_paths=[root / "mask" / f"{s}.png" for s in names] if has.get("mask") else None,
        flow_backward_paths=([None] + [root / "flow_backward" / f"{s}.npy" for s in names[1:]])
        if has.get("flow_backward") else None,
        occlusion_paths=([root / "occlusion" / f"{s}.png" for s in names[:-1]] + [None]) if has.get("occlusion") else None,
        row_pose_paths=[root / "row_poses" / f"{s}.npy" for s in names] if has.get("row_poses") else None,
        depth_exact_paths=[root / "depth_exact" / f"{s}.npy" for s in names]
        if has.get("depth_exact", (root / "depth_exact").is_dir()) else None,
        meta=header,
    )


def read_instance_poses(root: str | Path, i: int) -> dict[int, np.ndarray]:
    """``{instance id: (4, 4) float64 world_from_body}`` of the rigid movers at frame ``i`` (from
    ``frames/NNNNNN.json``); empty when the frame has none. Deforming surfaces are not rigid and
    carry no pose. InputError names the record when it is unreadable."""
    path = Path(root) / "frames" / f"{_name(i)}.json"
    try:
        rec = json.loads(path.read_text())
        return {int(k): np.asarray(v, np.float64).reshape(4, 4) for k, v in rec.get("instance_poses", {}).items()}
    except FileNotFoundError:
        raise InputError(path, "frame record is missing") from None
    except (OSError, json.JSONDecodeError, UnicodeDecodeError, TypeError, ValueError, AttributeError,
            RecursionError) as e:
        raise InputError(path, f"cannot read frame record ({type(e).__name__}: {str(e)[:80]})") from None


def _read_kitti_poses(path: Path, n: int) -> np.ndarray:
    try:
        rows = np.loadtxt(path, ndmin=2)
    except (OSError, ValueError) as e:
        raise InputError(path, f"cannot read poses ({e})") from None
    if rows.shape != (n, 12) or not np.isfinite(rows).all():
        raise InputError(path, f"expected {n} finite rows of 12 numbers, got shape {rows.shape}")
    out = np.tile(np.eye(4), (n, 1, 1))
    out[:, :3, :] = rows.reshape(n, 3, 4)
    return out


def _read_times(path: Path, n: int) -> np.ndarray:
    try:
        t = np.loadtxt(path, ndmin=1)
    except (OSError, ValueError) as e:
        raise InputError(path, f"cannot read times ({e})") from None
    if t.shape != (n,):
        raise InputError(path, f"expected {n} timestamps, got {t.shape[0]}")
    return t.astype(np.float64)
