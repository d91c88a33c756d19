"""``open_sequence``: the one entry point that opens any sequence folder deepslam reads.

It dispatches on the folder's content to the readers (:mod:`deepslam.core.ours`,
:mod:`deepslam.core.euroc`, :mod:`deepslam.core.kitti`), which build :class:`deepslam.core.sequence.Sequence`
objects; keeping the dispatcher apart from the Sequence class keeps the imports one-way
(sequence <- readers <- this module).
"""
from __future__ import annotations

from pathlib import Path

from deepslam.core.camera import check_flow_size
from deepslam.core.errors import InputError
from deepslam.core.euroc import read_euroc
from deepslam.core.kitti import read_kitti
from deepslam.core.ours import read_ours
from deepslam.core.sequence import Sequence
from deepslam.core.tum import is_tum, read_tum


def open_sequence(path: str | Path) -> Sequence:
    """Open a KITTI odometry sequence folder (``.../sequences/NN``), an EuRoC ASL folder (holding
    ``mav0``, or ``mav0`` itself), a TUM RGB-D folder (holding ``rgb.txt`` and ``depth.txt``) or a
    folder in our format (holding ``sequence.json``)."""
    path = Path(path)
    if not path.exists():
        raise InputError(path, "sequence folder does not exist")
    if not path.is_dir():
        raise InputError(path, "not a folder")
    if (path / "sequence.json").is_file():
        return read_ours(path)
    if (path / "mav0").is_dir() or path.name == "mav0":
        return read_euroc(path)
    if (path / "image_0").is_dir() or (path / "image_2").is_dir() or (path / "calib.txt").is_file():
        return read_kitti(path)
    if is_tum(path):
        return read_tum(path)
    raise InputError(path, "not a KITTI sequence (image_0/, calib.txt), EuRoC folder (mav0/), TUM RGB-D "
                     "folder (rgb.txt, depth.txt) or deepslam sequence (sequence.json)")


def open_sequence_for_flow(path: str | Path) -> Sequence:
    """:func:`open_sequence`, refusing (InputError naming the folder) a sequence whose images are too small
    for optical flow (:func:`core.camera.check_flow_size`): the commands that estimate flow between its
    frames (``vo``, ``slam``, ``tune-slam``, ``adapt``, ``validate-flow``) stop before any work."""
    seq = open_sequence(path)
    check_flow_size(seq.camera.width, seq.camera.height, path)
    return seq
