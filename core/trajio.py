"""Read and write trajectory files: KITTI, TUM and EuRoC ASL csv (plain, .xz or .gz).

Formats (one pose per line; blank lines and lines starting with ``#`` are skipped):

- ``kitti``: 12 numbers, the top 3x4 of ``world_from_cam`` row-major (r11 r12 r13 tx r21 ... tz);
  no timestamps (frames are matched by index). KITTI ground truth is cam0's pose, OpenCV axes.
- ``tum``: ``t x y z qx qy qz qw`` separated by spaces: time in seconds, position in metres,
  the unit quaternion in (x, y, z, w) order.
- ``euroc``: the ASL ground-truth csv: ``#timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z, ...``
  comma-separated, at least 8 columns (velocity and biases that follow are ignored), timestamps in
  integer nanoseconds, quaternion in (w, x, y, z) order. ASL ground truth is ``world_from_body``
  (the IMU frame); it is returned as it is: moving it to a camera with T_BS is the sequence reader's
  job (core/euroc.py).

:func:`read_trajectory` detects the format from the content when ``fmt`` is None: comma-separated
with integer nanosecond timestamps is ``euroc``, 8 columns ``tum``, 12 columns ``kitti``.

Every fault in a file raises :class:`core.errors.InputError` naming the file and the 1-based line:
wrong column count, a non-number, NaN or inf, a rotation that is not orthonormal (KITTI: max
|R^T R - I| or |det R - 1| above 1e-3), a quaternion whose norm is off 1 by more than 1e-3 (smaller
deviations are normalised away), a timestamp smaller than the one before, a file with no pose.
A timestamp equal to the one before (published estimates have a few, e.g. evo's V102.txt) is not an
error: the first pose at that time is kept and the repeats are dropped, so the returned timestamps
strictly increase (as :class:`core.trajectory.Trajectory` and interpolation need).
"""
from __future__ import annotations

import io
import lzma
import re
import warnings
import zlib
from pathlib import Path

import numpy as np

from deepslam.core import atomic, se3
from deepslam.core.errors import InputError
from deepslam.core.trajectory import Trajectory

FORMATS = ("kitti", "tum", "euroc")
"""The trajectory formats this module reads and writes."""

ROTATION_TOL = 1e-3
"""Largest accepted max |R^T R - I| (and |det R - 1|) of a KITTI rotation."""

QUAT_NORM_TOL = 1e-3
"""Largest accepted | |q| - 1 | of a TUM/EuRoC quaternion; smaller deviations are normalised."""

_SPLIT = re.compile(r"[\s,]+")
_INT = re.compile(r"^[+]?\d+$")
_NCOLS = {"kitti": 12, "tum": 8, "euroc": 8}
_DESCRIBE = {
    "kitti": "12 columns (KITTI: 3x4 world_from_cam, row-major)",
    "tum": "8 columns (TUM: t x y z qx qy qz qw)",
    "euroc": "at least 8 comma-separated columns (EuRoC: t_ns, p_x, p_y, p_z, q_w, q_x, q_y, q_z, ...)",
}


def default_format(sequence_kind: str, has_timestamps: bool = True) -> str:
    """The trajectory format ``vo`` and ``slam`` write for a sequence by default: the one its own dataset's
    tools read. ``kitti`` (3x4 rows matched by index) for a KITTI sequence or one without times, else
    ``tum`` (timestamped rows): EuRoC, TUM RGB-D and our format.

    Args:
        sequence_kind: ``Sequence.kind`` (``kitti``, ``euroc``, ``tum``, ``ours``).
        has_timestamps: whether the sequence has frame times.
    """
    return "kitti" if sequence_kind == "kitti" or not has_timestamps else "tum"


def ns_to_s(ns) -> np.ndarray:
    """Integer nanoseconds -> float64 seconds, the one conversion used by every reader (so that
    times from a data.csv and from a ground-truth csv compare exactly)."""
    return np.array([int(t) / 1e9 for t in ns], dtype=np.float64)


TEXT_MAX_BYTES = 64 * 1024 * 1024
"""Most bytes of a trajectory's text, stored or decompressed: about 500,000 TUM poses (KITTI 00's 4,541
poses take 0.7 MB; a 1 MB gzip of one repeated line would decompress to about 1 GB)."""


def _decompress_bounded(raw: bytes, kind: str, path: Path, limit: int) -> bytearray:
    """``raw`` decompressed (``kind`` ``xz`` or ``gz``, several gzip members included), stopping with an
    InputError naming ``path`` as soon as the output passes ``limit`` bytes: the memory used stays
    within ``limit`` whatever the file's compression ratio."""
    out = bytearray()
    data = raw
    while data:
        d = lzma.LZMADecompressor() if kind == "xz" else zlib.decompressobj(16 + zlib.MAX_WBITS)
        out += d.decompress(data, limit + 1 - len(out))
        if len(out) > limit:
            raise InputError(path, f"decompresses to more than {limit // 2**20} MiB; not a trajectory file")
        if not d.eof:
            raise InputError(path, f"broken compressed file (truncated {'xz' if kind == 'xz' else 'gzip'} stream)")
        data = d.unused_data
    return out


def read_text(path: str | Path, max_bytes: int = TEXT_MAX_BYTES) -> str:
    """The text of ``path``, decompressing .xz (lzma) and .gz transparently (by magic bytes), at most
    ``max_bytes`` stored or decompressed (:data:`TEXT_MAX_BYTES`; a compressed file is cut off as soon
    as its output passes it, so a decompression bomb costs no more memory than that).

    Raises InputError when the file is missing, a folder, unreadable, too large, a broken archive or not text.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(p, "no such file")
    if p.is_dir():
        raise InputError(p, "is a folder, not a trajectory file")
    try:
        size = p.stat().st_size
        if size > max_bytes:
            raise InputError(p, f"is {size // 2**20} MiB; a trajectory file is at most {max_bytes // 2**20} MiB")
        raw = p.read_bytes()
    except OSError as e:
        raise InputError(p, f"cannot read ({e.strerror or e})") from None
    try:
        if raw[:6] == b"\xfd7zXZ\x00" or p.suffix == ".xz":
            raw = _decompress_bounded(raw, "xz", p, max_bytes)
        elif raw[:2] == b"\x1f\x8b":
            raw = _decompress_bounded(raw, "gz", p, max_bytes)
    except (lzma.LZMAError, zlib.error, OSError, EOFError) as e:
        raise InputError(p, f"broken compressed file ({e})") from None
    if b"\0" in raw:
        raise InputError(p, "is a binary file, not a text trajectory")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise InputError(p, f"not UTF-8 text (byte {e.start})") from None


def _content_lines(text: str) -> list[tuple[int, str]]:
    """(1-based line number, stripped line) of every line that is neither blank nor a # comment."""
    return [(n, s) for n, s in enumerate((line.strip() for line in text.splitlines()), 1)
            if s and s[0] != "#"]


def _is_number(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True


def detect_format(path: str | Path, text: str | None = None) -> str:
    """``kitti``, ``tum`` or ``euroc`` from the first pose line of the file (see module docstring)."""
    text = read_text(path) if text is None else text
    return _detect(path, _content_lines(text))


def _detect(path: str | Path, lines: list[tuple[int, str]]) -> str:
    lines = _drop_csv_header(lines[:2])
    if not lines:
        raise InputError(path, "no poses in the file (empty or only comments)")
    n, line = lines[0]
    toks = _SPLIT.split(line)
    if "," in line and len(toks) >= 8 and _looks_like_ns(toks[0]):
        return "euroc"
    if len(toks) == 8:
        return "tum"
    if len(toks) == 12:
        return "kitti"
    raise InputError(path, f"cannot tell the format from {len(toks)} columns: expected {_DESCRIBE['kitti']}, "
                     f"{_DESCRIBE['tum']} or {_DESCRIBE['euroc']}", line=n)


def _looks_like_ns(tok: str) -> bool:
    """An integer (or a number >= 1e12) as the first csv column: a nanosecond timestamp."""
    if _INT.match(tok):
        return True
    try:
        return float(tok) >= 1e12
    except ValueError:
        return False


def _drop_csv_header(lines: list[tuple[int, str]]) -> list[tuple[int, str]]:
    """Drop a first csv line without '#' whose fields are all words (``timestamp,p_x,...``)."""
    if lines and "," in lines[0][1] and not any(_is_number(t) for t in _SPLIT.split(lines[0][1])):
        return lines[1:]
    return lines


def read_trajectory(path: str | Path, fmt: str | None = None) -> Trajectory:
    """Read a trajectory file (see :func:`read_trajectory_and_format`)."""
    return read_trajectory_and_format(path, fmt)[0]


def read_trajectory_and_format(path: str | Path, fmt: str | None = None) -> tuple[Trajectory, str]:
    """Read a trajectory file (KITTI, TUM or EuRoC csv; .xz/.gz accepted).

    Args:
        path: the file.
        fmt: ``kitti``, ``tum`` or ``euroc``; None detects it from the content.

    Returns:
        (Trajectory, fmt): ``world_from_cam`` (N, 4, 4) float64 (for EuRoC: world_from_body, as stored)
        and ``timestamps_s`` (N,) float64 seconds, or None for KITTI; the format read.

    Raises:
        InputError naming the file and line for any bad content (see module docstring).
    """
    path = Path(path)
    if fmt is not None and fmt not in FORMATS:
        raise InputError(None, f"unknown trajectory format {fmt!r} (one of {', '.join(FORMATS)})")
    lines = _content_lines(read_text(path))
    if fmt is None:
        fmt = _detect(path, lines)
    if fmt == "euroc":
        lines = _drop_csv_header(lines)
    if not lines:
        raise InputError(path, "no poses in the file (empty or only comments)")

    parsed = _parse_fast(lines, fmt)
    rows, ns = parsed if parsed is not None else _parse_checked(path, lines, fmt)

    line_of = [n for n, _ in lines]
    bad = ~np.isfinite(rows)
    if bad.any():
        k, col = np.argwhere(bad)[0]
        raise InputError(path, f"column {col + 1}: {_tok(lines[k][1], col)} is not a finite number",
                         line=line_of[k])

    if fmt == "kitti":
        rot = rows.reshape(-1, 3, 4)[:, :, :3]
        err = se3.orthonormality_error(rot)
        k = _first(err > ROTATION_TOL)
        if k is not None:
            raise InputError(path, f"rotation is not orthonormal (max |R^T R - I|, |det R - 1| = {err[k]:.3g} "
                             f"> {ROTATION_TOL:g})", line=line_of[k])
        poses = se3.from_rt(rot, rows.reshape(-1, 3, 4)[:, :, 3])
        return Trajectory(poses, None), fmt

    if fmt == "tum":
        times = rows[:, 0]
        pos = rows[:, 1:4]
        quat_xyzw = rows[:, 4:8]
    else:
        times = ns_to_s(ns)
        pos = rows[:, 1:4]
        quat_xyzw = rows[:, [5, 6, 7, 4]]
    norm = np.linalg.norm(quat_xyzw, axis=1)
    k = _first(np.abs(norm - 1.0) > QUAT_NORM_TOL)
    if k is not None:
        raise InputError(path, f"quaternion norm {norm[k]:.6g} is not 1 (tolerance {QUAT_NORM_TOL:g})",
                         line=line_of[k])
    # EuRoC: compare the integer nanoseconds (float seconds near 1.4e9 s resolve only ~0.2 us)
    dt = np.diff(np.array(ns, dtype=np.int64)) if fmt == "euroc" else np.diff(times)
    k = _first(dt < 0)
    if k is not None:
        raise InputError(path, f"timestamp {_tok(lines[k + 1][1], 0)} goes back in time "
                         f"(previous pose has {_tok(lines[k][1], 0)})", line=line_of[k + 1])
    keep = np.concatenate([[True], dt > 0])  # a repeated timestamp: keep its first pose
    if not keep.all():
        times, pos, quat_xyzw, norm = times[keep], pos[keep], quat_xyzw[keep], norm[keep]
    poses = se3.from_quat_xyzw(quat_xyzw / norm[:, None], pos)
    return Trajectory(poses, times), fmt


def _parse_fast(lines: list[tuple[int, str]], fmt: str) -> tuple[np.ndarray, list[int] | None] | None:
    """numpy.loadtxt on the pose lines (C speed); None when anything is off (then the line-by-line
    parser finds and reports the fault)."""
    ncols = _NCOLS[fmt]
    body = io.StringIO("\n".join(line for _, line in lines))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            if fmt == "euroc":
                ns = [int(line.split(",", 1)[0]) for _, line in lines]
                rows = np.loadtxt(body, delimiter=",", usecols=range(ncols), comments=None, ndmin=2, dtype=np.float64)
            else:
                ns = None
                rows = np.loadtxt(body, comments=None, ndmin=2, dtype=np.float64)
    except (ValueError, UserWarning):
        return None
    if rows.shape != (len(lines), ncols):
        return None
    return rows, ns


def _parse_checked(path: Path, lines: list[tuple[int, str]], fmt: str) -> tuple[np.ndarray, list[int] | None]:
    """Line-by-line parser that raises InputError at the first line with a wrong column count or a
    non-number."""
    ncols = _NCOLS[fmt]
    rows = np.empty((len(lines), ncols), dtype=np.float64)
    ns = [] if fmt == "euroc" else None
    for k, (n, line) in enumerate(lines):
        toks = _SPLIT.split(line)
        if len(toks) != ncols and not (fmt == "euroc" and len(toks) > ncols):
            raise InputError(path, f"expected {_DESCRIBE[fmt]}, got {len(toks)} columns", line=n)
        toks = toks[:ncols]
        try:
            rows[k] = [float(t) for t in toks]
        except ValueError:
            col = next(i for i, t in enumerate(toks) if not _is_number(t))
            raise InputError(path, f"column {col + 1}: {toks[col]!r} is not a number", line=n) from None
        if ns is not None:
            ns.append(int(toks[0]) if _INT.match(toks[0]) else int(round(float(toks[0]))))
    return rows, ns


def _tok(line: str, col: int) -> str:
    return repr(_SPLIT.split(line)[col])


def _first(mask: np.ndarray) -> int | None:
    idx = np.flatnonzero(mask)
    return int(idx[0]) if len(idx) else None


def format_trajectory(traj: Trajectory, fmt: str) -> str:
    """The text of ``traj`` in ``fmt`` (shortest round-trip float formatting, exact on re-reading
    except EuRoC timestamps, which are rounded to whole nanoseconds)."""
    if fmt not in FORMATS:
        raise ValueError(f"unknown trajectory format {fmt!r} (one of {', '.join(FORMATS)})")
    poses = traj.world_from_cam
    f = repr
    out: list[str] = []
    if fmt == "kitti":
        for p in poses[:, :3, :4].reshape(-1, 12):
            out.append(" ".join(f(float(v)) for v in p))
        return "\n".join(out) + ("\n" if out else "")
    if traj.timestamps_s is None:
        raise ValueError(f"the {fmt} format needs timestamps and this trajectory has none")
    q_xyzw = se3.to_quat_xyzw(poses)
    pos = poses[:, :3, 3]
    if fmt == "tum":
        out.append("# timestamp(s) tx ty tz qx qy qz qw")
        for t, p, q in zip(traj.timestamps_s, pos, q_xyzw):
            out.append(" ".join(f(float(v)) for v in (t, *p, *q)))
    else:
        out.append("#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []")
        for t, p, q in zip(traj.timestamps_s, pos, q_xyzw):
            vals = (*p, q[3], q[0], q[1], q[2])
            out.append(",".join([str(int(round(float(t) * 1e9)))] + [f(float(v)) for v in vals]))
    return "\n".join(out) + "\n"


def write_trajectory(path: str | Path, traj: Trajectory, fmt: str) -> None:
    """Write ``traj`` to ``path`` in ``fmt`` (``kitti``, ``tum`` or ``euroc``) atomically.

    Raises ValueError for an unknown format, or for tum/euroc when ``traj`` has no timestamps.
    """
    atomic.write_text(path, format_trajectory(traj, fmt))
