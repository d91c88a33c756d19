"""Text files of every reader that are not UTF-8, not a file, or hold impossible cameras: exit 2, one
line naming the file, no traceback (theseus-style: one parametrized test per fault class)."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
NOT_UTF8 = b"P0: 7.0e+02 0 6.0e+02 0 0 7.0e+02 1.8e+02 0 0 0 1 0\n\xff\xfe\xfa garbage\n"


@pytest.fixture(scope="module")
def sequences(tmp_path_factory, shared_data):
    """Small copies of a KITTI slice (5 frames), the EuRoC slice and one of our renders."""
    from deepslam.cli import main

    root = tmp_path_factory.mktemp("bad-text")
    kitti = root / "kitti"
    (kitti / "image_0").mkdir(parents=True)
    src = shared_data / "kitti" / "sequences" / "06"
    for i in range(5):
        shutil.copy(src / "image_0" / f"{i:06d}.png", kitti / "image_0")
    shutil.copy(src / "calib.txt", kitti / "calib.txt")
    (kitti / "times.txt").write_text("".join(f"{0.1 * i:.6f}\n" for i in range(5)))
    euroc = root / "euroc"
    shutil.copytree(next(p for p in (shared_data / "euroc").iterdir() if (p / "mav0").is_dir()), euroc)
    ours = root / "ours"
    assert main(["render", "--scene", "room", "--frames", "2", "--width", "64", "--out", str(ours), "--quiet"]) == 0
    return {"kitti": kitti, "euroc": euroc, "ours": ours}


CASES = {
    "kitti calib.txt not UTF-8": ("kitti", "calib.txt", NOT_UTF8, "not UTF-8"),
    "kitti times.txt not UTF-8": ("kitti", "times.txt", b"0.0\n\xc3\x28\n", "not UTF-8"),
    "kitti calib.txt is a folder": ("kitti", "calib.txt", None, "is a folder"),
    "kitti fx <= 0": ("kitti", "calib.txt", b"P0: -7.0e+02 0 6.0e+02 0 0 7.0e+02 1.8e+02 0 0 0 1 0\n", "usable camera"),
    "euroc data.csv not UTF-8": ("euroc", "mav0/cam0/data.csv", b"#timestamp,filename\n\x80\x81\n", "not UTF-8"),
    "euroc sensor.yaml not UTF-8": ("euroc", "mav0/cam0/sensor.yaml", b"\xff\xfe\x00a: 1\n", "not UTF-8"),
    "ours sequence.json not UTF-8": ("ours", "sequence.json", b'{"format": "\xff"}', "not UTF-8"),
    "ours sequence.json a list": ("ours", "sequence.json", b"[1, 2, 3]", "expected a JSON object"),
    "ours sequence.json camera fx 0": ("ours", "sequence.json", None, "bad header field"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_text_file_is_one_line_exit_2(case, sequences, tmp_path, capsys):
    import json

    from deepslam.cli import main

    kind, rel, content, what = CASES[case]
    seq = tmp_path / kind
    shutil.copytree(sequences[kind], seq)
    target = seq / rel
    if case == "kitti calib.txt is a folder":
        target.unlink()
        target.mkdir()
    elif case == "ours sequence.json camera fx 0":
        header = json.loads(target.read_text())
        header["camera"]["fx"] = 0
        target.write_text(json.dumps(header))
    else:
        target.write_bytes(content)
    rc = main(["info", str(seq)])
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert rel.split("/")[-1] in lines[0] and what in lines[0], lines[0]


def test_a_full_disk_is_one_line_exit_2_and_leaves_no_partial_file(tmp_path, capsys):
    """ENOSPC on a small tmpfs where the machine allows mounting one (root in a container); else skip."""
    import os
    import subprocess

    from deepslam.cli import main

    mnt = tmp_path / "tiny"
    mnt.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mnt)],
                                           capture_output=True).returncode != 0:
        pytest.skip("cannot mount a small tmpfs here (needs root and mount permission)")
    try:
        rc = main(["render", "--scene", "street", "--frames", "4", "--width", "320", "--out", str(mnt / "seq"), "--quiet"])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and "No space left on device" in err[0], err
        leftovers = [p for p in mnt.rglob("*") if p.is_file() and ".tmp" in p.name]
        assert leftovers == []  # atomic writes removed their temporary files
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)
