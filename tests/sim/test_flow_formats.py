"""Flow in the exchange formats (Middlebury .flo, KITTI 2015 flow PNG) beside the .npy in every layout,
and the TUM RGB-D export read back by open_sequence and `deepslam info --check`."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from deepslam.core import flowio
from deepslam.core.errors import InputError
from deepslam.core.readers import open_sequence
from deepslam.scenes import SceneConfig
from deepslam.sim import RenderConfig, SimConfig, TrajectoryConfig, render_sequence

KITTI_TOL = 0.5 / 64 + 1e-6  # rounding to 1/64 px
TUM_DEPTH_MAX_M = 65535 / 5000.0


def _cfg(scene="room", formats=("npy", "flo", "png")):
    return SimConfig(SceneConfig(name=scene, seed=3, moving_objects=1, texture_px_per_m=20),
                     TrajectoryConfig(frames=3), RenderConfig(width=160, stereo_baseline_m=0.0, flow_formats=formats))


def _random_flow(rng, h=7, w=9):
    flow = rng.normal(0, 40, (h, w, 2)).astype(np.float32)
    flow[1, 2] = np.nan
    flow[3, 4, 1] = np.nan
    flow[5, 0, 0] = 600.0  # beyond the KITTI PNG's range
    return flow


# --- the formats on their own ---------------------------------------------------------------------

def test_flo_bytes_follow_middlebury_and_round_trip(tmp_path):
    flow = _random_flow(np.random.default_rng(0))
    path = tmp_path / "a.flo"
    flowio.write_flo(path, flow)
    raw = path.read_bytes()
    assert raw[:4] == b"PIEH" and np.frombuffer(raw[:4], "<f4")[0] == np.float32(202021.25)
    assert tuple(np.frombuffer(raw[4:12], "<i4")) == (9, 7)  # width, height
    data = np.frombuffer(raw[12:], "<f4").reshape(7, 9, 2)  # u, v interleaved, row by row
    known = np.isfinite(flow).all(axis=2)
    assert np.array_equal(data[known], flow[known])
    assert (data[~known] == np.float32(1e10)).all()
    back = flowio.read_flo(path)
    assert back.dtype == np.float32 and back.shape == flow.shape
    assert np.array_equal(back[known], flow[known]) and np.isnan(back[~known]).all()


def test_kitti_png_channels_and_round_trip(tmp_path):
    flow = _random_flow(np.random.default_rng(1))
    path = tmp_path / "a.png"
    flowio.write_kitti_flow_png(path, flow)
    bgr = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert bgr.dtype == np.uint16 and bgr.shape == (7, 9, 3)
    valid = np.isfinite(flow).all(axis=2) & (np.abs(flow) < 511).all(axis=2)
    assert np.array_equal(bgr[..., 0] == 1, valid) and (bgr[~valid] == 0).all()  # B = valid
    np.testing.assert_allclose((bgr[..., 2][valid] - 2.0 ** 15) / 64, flow[..., 0][valid], atol=KITTI_TOL, rtol=0)  # R = u
    np.testing.assert_allclose((bgr[..., 1][valid] - 2.0 ** 15) / 64, flow[..., 1][valid], atol=KITTI_TOL, rtol=0)  # G = v
    back = flowio.read_kitti_flow_png(path)
    assert back.dtype == np.float32 and back.shape == flow.shape
    np.testing.assert_allclose(back[valid], flow[valid], atol=KITTI_TOL, rtol=0)
    assert np.isnan(back[~valid]).all()


def test_readers_refuse_broken_files(tmp_path):
    flowio.write_flo(tmp_path / "a.flo", np.zeros((4, 5, 2), np.float32))
    (tmp_path / "short.flo").write_bytes((tmp_path / "a.flo").read_bytes()[:-4])
    (tmp_path / "magic.flo").write_bytes(b"HEIP" + (tmp_path / "a.flo").read_bytes()[4:])
    cv2.imwrite(str(tmp_path / "grey.png"), np.zeros((4, 5), np.uint8))
    for read, name, what in ((flowio.read_flo, "short.flo", "needs"), (flowio.read_flo, "magic.flo", "magic"),
                             (flowio.read_flo, "none.flo", "missing"), (flowio.read_kitti_flow_png, "grey.png", "16-bit")):
        with pytest.raises(InputError, match=what):
            read(tmp_path / name)


# --- in the renders -------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    """The same tiny render in our format (npy only: the reference) and in every layout with all formats."""
    root = tmp_path_factory.mktemp("flow_formats")
    out = {"ref": render_sequence(_cfg(formats=("npy",)), root / "ref", progress=False)}
    for fmt in ("ours", "kitti", "euroc", "tum"):
        out[fmt] = render_sequence(_cfg(), root / fmt, fmt=fmt, progress=False)
    return out


def _flow_folder(path: Path, fmt: str) -> Path:
    return path / "mav0" / "cam0" if fmt == "euroc" else path


@pytest.mark.parametrize("fmt", ["ours", "kitti", "euroc", "tum"])
def test_flow_files_equal_the_npy_in_every_layout(renders, fmt):
    ref = open_sequence(renders["ref"])
    base = _flow_folder(renders[fmt], fmt)
    checked = 0
    for folder, frames, get in (("flow", range(len(ref) - 1), ref.flow), ("flow_backward", range(1, len(ref)), ref.flow_backward)):
        assert sorted(p.name for p in (base / folder).iterdir()) == sorted(
            f"{i:06d}.{ext}" for i in frames for ext in ("npy", "flo", "png"))
        for i in frames:
            want = get(i)
            npy = np.load(base / folder / f"{i:06d}.npy")
            assert np.array_equal(npy, want, equal_nan=True)  # the same render, byte for byte
            flo = flowio.read_flo(base / folder / f"{i:06d}.flo")
            assert np.array_equal(flo, want, equal_nan=True)  # float32: exact, NaN = unknown
            png = flowio.read_kitti_flow_png(base / folder / f"{i:06d}.png")
            valid = np.isfinite(want).all(axis=2) & (np.abs(want) < 511).all(axis=2)
            np.testing.assert_allclose(png[valid], want[valid], atol=KITTI_TOL, rtol=0)
            assert np.isnan(png[~valid]).all()
            checked += 1
    assert checked == 2 * (len(ref) - 1)


def test_frame_records_cover_the_extra_flow_files(renders):
    """--resume trusts a frame only while its files hash to its record: the .flo/.png files are listed."""
    rec = json.loads((renders["ours"] / "frames" / "000000.json").read_text())
    assert {"flow/000000.flo", "flow/000000.png", "flow/000000.npy"} <= set(rec["files"])
    rec = json.loads((renders["ours"] / "frames" / "000001.json").read_text())
    assert {"flow_backward/000001.flo", "flow_backward/000001.png"} <= set(rec["files"])


def test_tum_export_reads_back(renders):
    ref, tum = open_sequence(renders["ref"]), open_sequence(renders["tum"])
    assert tum.kind == "tum" and len(tum) == len(ref)
    assert tum.camera == ref.camera
    assert tum.gt_frames is None or list(tum.gt_frames) == list(range(len(ref)))
    np.testing.assert_allclose(tum.timestamps_s, ref.timestamps_s, atol=5e-7, rtol=0)
    np.testing.assert_allclose(tum.gt.world_from_cam, ref.gt.world_from_cam, atol=1e-12, rtol=0)
    for i in range(len(ref)):
        assert np.array_equal(tum.image(i), ref.image(i))
        want, got = ref.depth(i), tum.depth(i)
        assert got.dtype == np.float32 and got.shape == want.shape
        fits = (want > 0) & (want * 5000 < 65535.5)
        assert fits.mean() > 0.5
        np.testing.assert_allclose(got[fits], want[fits], atol=0.5 / 5000 + 1e-6, rtol=0)
        assert (got[~fits] == 0).all()  # 0 where the render had none, and beyond 16 bits' 13.107 m
        assert np.array_equal(cv2.imread(str(renders["tum"] / "mask" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED), ref.mask(i))
    assert (renders["tum"] / "intrinsics.txt").read_text().split() == [repr(v) for v in (ref.camera.fx, ref.camera.fy,
                                                                                         ref.camera.cx, ref.camera.cy)]
    assert "freiburg" not in renders["tum"].name


def test_tum_export_passes_info_check(renders, capsys):
    from deepslam.cli import main

    assert main(["info", str(renders["tum"]), "--check", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["kind"] == "tum" and info["frames"] == 3 and info["ground_truth_frames"] == 3 and info["has_depth"]


@pytest.mark.parametrize("args, what", [
    (["--flow-format", "npy,bmp"], "unknown flow format 'bmp'"),
    (["--flow-format", ""], "unknown flow format"),
    (["--flow-format", "flo", "--no-flow"], "need the flow"),
])
def test_bad_flow_format_exits_2_with_one_line(tmp_path, capsys, args, what):
    from deepslam.cli import main

    out = tmp_path / "out"
    rc = main(["render", "--out", str(out), "--frames", "2", "--width", "32", *args])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and what in err, err
    assert not out.exists()


def test_cli_flow_format_reaches_the_config(tmp_path):
    from deepslam.cli import main

    out = tmp_path / "out"
    assert main(["render", "--out", str(out), "--frames", "2", "--width", "32", "--scene", "room",
                 "--flow-format", "png", "--quiet"]) == 0
    assert sorted(p.name for p in (out / "flow").iterdir()) == ["000000.npy", "000000.png"]
    assert json.loads((out / "sequence.json").read_text())["config"]["render"]["flow_formats"] == ["png"]
