"""One Sequence type for KITTI odometry, EuRoC ASL and our own format; images load lazily.

A :class:`Sequence` holds paths and metadata only, so thousands of frames never sit in memory.
Use :func:`open_sequence` to read any of the three layouts.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Callable, Iterator

import cv2
import numpy as np

from deepslam.core import flowio
from deepslam.core.camera import PinholeCamera
from deepslam.core.errors import InputError
from deepslam.core.imageio import read_image, read_npy  # noqa: F401 - read_image stays importable from here
from deepslam.core.trajectory import Trajectory


def dataset_file(folder: Path, name: str, listing: Path, line: int | None = None) -> Path:
    """``folder / name`` for a file name a dataset's listing gives (EuRoC data.csv, TUM rgb.txt), kept
    inside ``folder``: an absolute name, a ``..`` component or an empty name is an InputError naming the
    listing and its line (judged on the name as written; symbolic links inside the dataset are followed
    as usual)."""
    parts = PurePosixPath(name.replace("\\", "/")).parts
    if (not name.strip() or name.startswith(("/", "\\", "~")) or PureWindowsPath(name).drive or ".." in parts):
        raise InputError(listing, f"file name {name[:80]!r} leaves the dataset folder (absolute or with '..'); "
                                  "names must be relative to it", line=line)
    return folder / name


def ground_truth_files(beside: Callable[[str, str], list[Path] | None]) -> dict:
    """The Sequence fields of the ground-truth folders that sit beside a layout's images
    (``depth/``, ``depth_exact/``, ``flow/``, ``flow_backward/``, ``occlusion/``, ``mask/``, ``row_poses/``, one file per frame in the
    images' numbering), from ``beside(folder, suffix)`` -> per-frame paths or None when the folder is
    absent. Forward flow and occlusion have no file for the last frame, backward flow none for the first."""
    flow, back, occ = beside("flow", ".npy"), beside("flow_backward", ".npy"), beside("occlusion", ".png")
    return {"depth_paths": beside("depth", ".npy"), "mask_paths": beside("mask", ".png"),
            "flow_paths": None if flow is None else flow[:-1] + [None],
            "flow_backward_paths": None if back is None else [None] + back[1:],
            "occlusion_paths": None if occ is None else occ[:-1] + [None],
            "row_pose_paths": beside("row_poses", ".npy"), "depth_exact_paths": beside("depth_exact", ".npy")}


@dataclasses.dataclass(frozen=True)
class Frame:
    """One frame of a sequence; its arrays load when asked for."""

    sequence: "Sequence"
    index: int
    """0-based frame index."""
    timestamp_s: float
    """Seconds (float64), in the sequence's clock."""

    @property
    def world_from_cam(self) -> np.ndarray | None:
        """(4, 4) float64 ground-truth pose of the (left) camera, OpenCV axes, or None."""
        return self.sequence.gt_pose(self.index)

    def image(self) -> np.ndarray:
        return self.sequence.image(self.index)

    def image_right(self) -> np.ndarray:
        return self.sequence.image_right(self.index)

    def depth(self) -> np.ndarray | None:
        return self.sequence.depth(self.index)

    def flow(self) -> np.ndarray | None:
        return self.sequence.flow(self.index)

    def mask(self) -> np.ndarray | None:
        return self.sequence.mask(self.index)


@dataclasses.dataclass(eq=False)
class Sequence:
    """A sequence of (stereo) frames with a rectified pinhole camera and optional ground truth.

    Attributes:
        name: human-readable name ("kitti/06", "euroc/V1_01_easy", or the folder name).
        kind: "kitti", "euroc" or "ours".
        root: the folder it was read from.
        camera: intrinsics of the images as served by :meth:`image` (rectified, undistorted).
        timestamps_s: (N,) float64 seconds.
        image_paths: N paths of the left (cam0) images.
        right_paths: N paths of the right images, or None.
        baseline_m: stereo baseline in metres (right camera at +baseline along x), or None.
        gt: ground-truth world_from_cam of the left camera at the frame times, or None.
        depth_paths / flow_paths / mask_paths: per-frame paths where the data has them (flow: None
            for the last frame), else None.
        postprocess: function (image, side) -> image applied after loading (EuRoC undistortion and
            rectification); side is "left" or "right".
        gt_frames: indices of the frames ``gt`` covers, in order, when it does not cover all (TUM's
            motion capture starts late): ``gt`` then has one pose per entry. None: one per frame.
        depth_reader: function path -> (H, W) float32 depth_z in metres for depth files that are not
            this project's .npy (TUM's 16-bit PNGs); None: .npy.
        flow_backward_paths / occlusion_paths: per-frame paths of the backward flow (None for frame 0)
            and the occlusion masks (None for the last frame), where the data has them.
        row_pose_paths: per-frame paths of the rolling shutter's per-row poses (renders with
            ``--rolling-shutter-ms``), or None.
        depth_exact_paths: per-frame paths of the exact depth where ``depth_paths`` hold a simulated
            sensor's (renders with ``--depth-noise``), or None (the depth is the exact one, or a real
            sensor's with nothing better).
    """

    name: str
    kind: str
    root: Path
    camera: PinholeCamera
    timestamps_s: np.ndarray
    image_paths: list[Path]
    right_paths: list[Path] | None = None
    baseline_m: float | None = None
    gt: Trajectory | None = None
    depth_paths: list[Path] | None = None
    flow_paths: list[Path | None] | None = None
    mask_paths: list[Path] | None = None
    postprocess: Callable[[np.ndarray, str], np.ndarray] | None = None
    meta: dict = dataclasses.field(default_factory=dict)
    gt_frames: np.ndarray | None = None
    depth_reader: Callable[[Path], np.ndarray] | None = None
    flow_backward_paths: list[Path | None] | None = None
    occlusion_paths: list[Path | None] | None = None
    row_pose_paths: list[Path] | None = None
    depth_exact_paths: list[Path] | None = None

    def __len__(self) -> int:
        return len(self.image_paths)

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self.frame(i)

    def frame(self, i: int) -> Frame:
        return Frame(self, i, float(self.timestamps_s[i]))

    def _sized(self, path: Path, arr: np.ndarray, what: str, tail: tuple[int, ...] = ()) -> np.ndarray:
        """``arr`` when its first two axes are the camera's (H, W) (and the rest ``tail`` when given),
        else InputError naming the file: every frame of a sequence is read at the camera's size, never
        silently resized or remapped."""
        h, w = self.camera.height, self.camera.width
        if arr.shape[:2] != (h, w) or (tail and arr.shape[2:] != tail):
            if tail:
                raise InputError(path, f"{what} is {arr.shape}, expected {(h, w, *tail)} (the camera is {w}x{h})")
            got = f"{arr.shape[1]}x{arr.shape[0]}" if arr.ndim >= 2 else str(arr.shape)
            raise InputError(path, f"{what} is {got}, expected {w}x{h} (the camera's size)")
        return arr

    def image(self, i: int) -> np.ndarray:
        """Left image i: uint8 (H, W) grey or (H, W, 3) RGB, rectified. InputError naming the file when
        the image on disk is not the camera's size."""
        img = self._sized(self.image_paths[i], read_image(self.image_paths[i]), "image")
        return self.postprocess(img, "left") if self.postprocess else img

    def image_right(self, i: int) -> np.ndarray:
        if self.right_paths is None:
            raise InputError(self.root, "sequence has no right images")
        img = self._sized(self.right_paths[i], read_image(self.right_paths[i]), "image")
        return self.postprocess(img, "right") if self.postprocess else img

    def depth(self, i: int) -> np.ndarray | None:
        """(H, W) float32 depth_z in metres, 0 where unknown; None when the sequence has no depth."""
        if self.depth_paths is None:
            return None
        if self.depth_reader is not None:
            return self._sized(self.depth_paths[i], self.depth_reader(self.depth_paths[i]), "depth")
        return self._sized(self.depth_paths[i], read_npy(self.depth_paths[i], np.float32, 2), "depth")

    def depth_exact(self, i: int) -> np.ndarray | None:
        """(H, W) float32 depth_z in metres of the scene's true surfaces (0 = nothing), for a render whose
        :meth:`depth` is a simulated sensor's; otherwise :meth:`depth` (the best geometry there is)."""
        if self.depth_exact_paths is None:
            return self.depth(i)
        return self._sized(self.depth_exact_paths[i], read_npy(self.depth_exact_paths[i], np.float32, 2), "depth")

    def gt_pose(self, i: int) -> np.ndarray | None:
        """(4, 4) float64 world_from_cam of frame i, or None where there is no ground truth."""
        if self.gt is None:
            return None
        if self.gt_frames is None:
            return self.gt.world_from_cam[i]
        k = int(np.searchsorted(self.gt_frames, i))
        return self.gt.world_from_cam[k] if k < len(self.gt_frames) and self.gt_frames[k] == i else None

    def flow(self, i: int) -> np.ndarray | None:
        """(H, W, 2) float32 flow (du, dv) px from frame i to i+1; None where absent (last frame)."""
        if self.flow_paths is None or self.flow_paths[i] is None:
            return None
        return self._sized(self.flow_paths[i], read_npy(self.flow_paths[i], np.float32, 3), "flow", (2,))

    def flow_backward(self, i: int) -> np.ndarray | None:
        """(H, W, 2) float32 flow (du, dv) px from frame i to i-1; None where absent (frame 0)."""
        if self.flow_backward_paths is None or self.flow_backward_paths[i] is None:
            return None
        return self._sized(self.flow_backward_paths[i], read_npy(self.flow_backward_paths[i], np.float32, 3), "flow",
                           (2,))

    def occlusion(self, i: int) -> np.ndarray | None:
        """(H, W) bool, True where the surface seen at a pixel of frame i is not visible in frame i+1
        (hidden, or outside the image); None where absent (the last frame)."""
        if self.occlusion_paths is None or self.occlusion_paths[i] is None:
            return None
        return self._sized(self.occlusion_paths[i], read_image(self.occlusion_paths[i]), "occlusion mask") > 0

    def row_poses(self, i: int) -> np.ndarray | None:
        """(H, 4, 4) float64 world_from_cam at each image row's capture time (a rolling-shutter render);
        None for a global shutter (every row is seen from :meth:`gt_pose`)."""
        if self.row_pose_paths is None:
            return None
        poses = read_npy(self.row_pose_paths[i], np.float64, 3)
        if poses.shape[0] != self.camera.height or poses.shape[1:] != (4, 4):
            raise InputError(self.row_pose_paths[i], f"expected ({self.camera.height}, 4, 4) row poses, got {poses.shape}")
        return poses

    def mask(self, i: int) -> np.ndarray | None:
        """(H, W) uint16 instance ids, 0 = static scene; None when absent."""
        if self.mask_paths is None:
            return None
        return self._sized(self.mask_paths[i], read_image(self.mask_paths[i]), "mask").astype(np.uint16, copy=False)

    def check(self, i: int) -> None:
        """Decode everything of frame i a later command would read and check it against the camera:
        image size, depth (H, W) finite and >= 0, flow (H, W, 2) finite, mask (H, W), backward flow,
        occlusion mask, rolling-shutter row poses, exact depth, and the flow's .flo / KITTI .png copies
        (headers and sizes). InputError naming the file otherwise."""
        h, w = self.camera.height, self.camera.width
        items = [(self.image_paths[i], self.image(i))]
        if self.right_paths is not None:
            items.append((self.right_paths[i], self.image_right(i)))
        for path, img in items:
            if img.shape[:2] != (h, w):
                raise InputError(path, f"image is {img.shape[1]}x{img.shape[0]}, the camera is {w}x{h}")
        d = self.depth(i)
        if d is not None:
            if d.shape != (h, w):
                raise InputError(self.depth_paths[i], f"depth is {d.shape}, expected ({h}, {w})")
            if not np.isfinite(d).all() or (d < 0).any():
                raise InputError(self.depth_paths[i], "depth has NaN, infinite or negative values (0 = unknown)")
        f = self.flow(i)
        if f is not None:
            if f.shape != (h, w, 2):
                raise InputError(self.flow_paths[i], f"flow is {f.shape}, expected ({h}, {w}, 2)")
            if not np.isfinite(f).all():
                raise InputError(self.flow_paths[i], "flow has NaN or infinite values")
        m = self.mask(i)
        if m is not None and m.shape[:2] != (h, w):
            raise InputError(self.mask_paths[i], f"mask is {m.shape}, expected ({h}, {w})")
        fb = self.flow_backward(i)  # sized by the reader
        if fb is not None and not np.isfinite(fb).all():
            raise InputError(self.flow_backward_paths[i], "backward flow has NaN or infinite values")
        self.occlusion(i)
        self.row_poses(i)
        if self.depth_exact_paths is not None:
            de = self.depth_exact(i)
            if not np.isfinite(de).all() or (de < 0).any():
                raise InputError(self.depth_exact_paths[i], "exact depth has NaN, infinite or negative values")
        # the flow in the other formats a render writes beside the .npy (Middlebury .flo, KITTI 2015 .png)
        for paths in (self.flow_paths, self.flow_backward_paths):
            if paths is None or paths[i] is None:
                continue
            for other, read in ((paths[i].with_suffix(".flo"), flowio.read_flo),
                                (paths[i].with_suffix(".png"), flowio.read_kitti_flow_png)):
                shape = read(other).shape if other.is_file() else (h, w, 2)
                if shape != (h, w, 2):
                    raise InputError(other, f"flow is {shape}, expected ({h}, {w}, 2)")

    def check_timestamps(self) -> None:
        """InputError unless the frame times are finite and strictly increasing."""
        t = np.asarray(self.timestamps_s, dtype=np.float64)
        if not np.isfinite(t).all():
            raise InputError(self.root, "frame timestamps are not all finite")
        bad = np.flatnonzero(np.diff(t) <= 0)
        if len(bad):
            raise InputError(self.root, f"frame timestamps do not increase at frame {int(bad[0]) + 1} "
                                        f"({t[bad[0]]:.6f} s then {t[bad[0] + 1]:.6f} s)")

    @property
    def has_depth(self) -> bool:
        return self.depth_paths is not None

    @property
    def has_stereo(self) -> bool:
        return self.right_paths is not None and self.baseline_m is not None


def check_read_width(read_width_px: int) -> None:
    """InputError unless ``read_width_px`` (``--read-width``) is in 0..8192 px."""
    if not 0 <= read_width_px <= 8192:
        raise InputError(None, f"--read-width must be in 0..8192 px, got {read_width_px}")


def read_for_estimated_flow(seq, read_width_px: int, flow: str, reads_depth):
    """``seq`` as a flow -> pose network reads it: an :class:`UpsampledView` ``read_width_px`` wide where the frames
    are narrower, the flow is estimated (``flow`` is not ``"gt"``) and the network does not read depth
    (``reads_depth``: a callable without arguments, asked only when the first two hold, so that a model file's
    header is read only where it matters); else ``seq`` itself. ``deepslam vo`` and supervised training read frames
    by this one rule."""
    if read_width_px > seq.camera.width and flow != "gt" and not reads_depth():
        return UpsampledView(seq, read_width_px)
    return seq


class UpsampledView:
    """A sequence read at a larger size: its images (and right images) upsampled bicubically to ``width`` px wide
    (the height in proportion), its camera scaled likewise (pixel centres kept: ``c' = s (c + 0.5) - 0.5``);
    everything else is the sequence's own. For estimated flow on the images only: depth and stored flow stay at
    the recorded size, so a network that reads them, or ``--flow gt``, does not take this view."""

    def __init__(self, seq, width: int):
        self._seq = seq
        cam = seq.camera
        self.size = (int(width), int(round(cam.height * width / cam.width)))
        self.camera = cam.scaled(*self.size)

    def __len__(self) -> int:
        return len(self._seq)

    def __getattr__(self, name):
        return getattr(self._seq, name)

    def image(self, i: int) -> np.ndarray:
        return cv2.resize(self._seq.image(i), self.size, interpolation=cv2.INTER_CUBIC)

    def image_right(self, i: int) -> np.ndarray:
        return cv2.resize(self._seq.image_right(i), self.size, interpolation=cv2.INTER_CUBIC)
