"""`deepslam slam` and `deepslam tune-slam` end to end on a small synthetic revisit sequence."""
from __future__ import annotations

import json

import pytest

from deepslam.core.trajio import read_trajectory, read_trajectory_and_format
from deepslam.cli import main
from deepslam.slam.synthetic import write_loop_sequence


@pytest.fixture(scope="module")
def seq_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli_loopseq")
    write_loop_sequence(root, n_frames=60, laps=2.0, lap_offset_m=0.2, seed=2)
    return root


def test_slam_cli_writes_trajectories_record_and_plot(seq_dir, tmp_path, capsys):
    out = tmp_path / "run" / "traj.txt"
    # revisits are 30 frames apart (the default T_loop, 50, would admit none)
    (tmp_path / "p20.json").write_text(json.dumps({"format": "deepslam-slam-params-v1", "c_s": 1.0, "c_r": 1.0,
                                                    "t_loop": 20}))
    rc = main(["slam", "--sequence", str(seq_dir), "--odometry", "gt-noisy", "--out", str(out),
               "--params", str(tmp_path / "p20.json"),
               "--plot", str(tmp_path / "p.png"), "--save-vocabulary", str(tmp_path / "voc.npz")])
    assert rc == 0
    text = capsys.readouterr().out
    assert "ATE rmse" in text and "loops" in text
    # our format has frame times: TUM rows by default (KITTI rows only for KITTI sequences)
    slam, slam_fmt = read_trajectory_and_format(out)
    vo, vo_fmt = read_trajectory_and_format(tmp_path / "run" / "traj_vo.txt")
    assert slam_fmt == vo_fmt == "tum" and slam.timestamps_s is not None
    assert len(slam) == len(vo) == 60
    rec = json.loads((tmp_path / "run" / "traj.json").read_text())
    assert rec["n_loops"] >= 9  # of the 10 keyframes (every 3rd frame) on the second lap
    # the frames inside a cycle a loop edge closes: at least the longest loop's span, at most all the loops' span
    first, last = min(min(p) for p in rec["loops"]), max(max(p) for p in rec["loops"])
    longest = max(abs(j - i) + 1 for i, j in rec["loops"])
    assert longest <= rec["frames_in_closed_cycles"] <= last - first + 1 and "closed cycles" in text
    # the ATE split over those frames and the others adds up to the whole, for the VO and the SLAM trajectory
    n_in = rec["frames_in_closed_cycles"]
    for m in (rec["metrics_vo"], rec["metrics_slam"]):
        parts = n_in * m["ate_in_closed_cycles_m"] ** 2 + (60 - n_in) * (m["ate_elsewhere_m"] or 0.0) ** 2
        assert parts == pytest.approx(60 * m["ate_m"] ** 2)
    assert "in closed cycles" in text
    # the same graph with an exact loop edge on every revisit (T_loop 20 apart, the second lap 0.2 m aside)
    perfect = rec["metrics_perfect_loops"]
    assert 20 <= perfect["revisit_pairs"] <= 40 and perfect["ate_m"] < 0.5 * rec["metrics_vo"]["ate_m"]
    assert "with perfect loops" in text
    assert rec["metrics_slam"]["ate_m"] < 0.5 * rec["metrics_vo"]["ate_m"]
    assert (tmp_path / "p.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the saved vocabulary and a params file are read back; TUM output carries timestamps
    (tmp_path / "p.json").write_text(json.dumps({"format": "deepslam-slam-params-v1", "c_s": 2.0, "c_r": 5.0,
                                                  "t_loop": 10}))
    rc = main(["slam", "--sequence", str(seq_dir), "--odometry", "gt-noisy", "--out", str(tmp_path / "t.tum"),
               "--format", "tum", "--vocabulary", str(tmp_path / "voc.npz"), "--params", str(tmp_path / "p.json"),
               "--json"])
    assert rc == 0
    rec2 = json.loads(capsys.readouterr().out)
    assert rec2["params"]["t_loop"] == 10 and rec2["params"]["c_r"] == 5.0
    assert read_trajectory(tmp_path / "t.tum").timestamps_s is not None
    rc = main(["slam", "--sequence", str(seq_dir), "--odometry", "gt-noisy", "--out", str(tmp_path / "t.kitti"),
               "--format", "kitti", "--vocabulary", str(tmp_path / "voc.npz"), "--quiet"])
    assert rc == 0 and "ATE rmse" in capsys.readouterr().out
    assert len(read_trajectory(tmp_path / "t.kitti", "kitti")) == 60


def test_slam_cli_bad_input_is_one_line_exit_2(seq_dir, tmp_path, capsys):
    rc = main(["slam", "--sequence", str(tmp_path / "nope"), "--odometry", "gt-noisy", "--out", str(tmp_path / "t.txt")])
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "does not exist" in err[0]
    (tmp_path / "bad.json").write_text("{not json")
    rc = main(["slam", "--sequence", str(seq_dir), "--odometry", "gt-noisy", "--out", str(tmp_path / "t.txt"),
               "--params", str(tmp_path / "bad.json")])
    assert rc == 2
    assert "bad.json" in capsys.readouterr().err
    assert not (tmp_path / "t.txt").exists()
    rc = main(["slam", "--sequence", str(seq_dir), "--model-cons", str(tmp_path / "missing.pt"),
               "--out", str(tmp_path / "t.txt")])
    assert rc == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_tune_slam_cli_writes_params_the_slam_cli_reads(seq_dir, tmp_path, capsys):
    out = tmp_path / "params.json"
    rc = main(["tune-slam", "--sequence", str(seq_dir), "--odometry", "gt-noisy", "--out", str(out),
               "--c-s", "1", "--c-r", "1,10", "--t-loop", "10,40", "--method", "coordinate"])
    assert rc == 0
    assert "best:" in capsys.readouterr().out
    rec = json.loads(out.read_text())
    assert rec["format"] == "deepslam-slam-params-v1" and rec["search"]
    # revisits are 30 frames apart: T_loop 40 admits no loop, so 10 must win
    assert rec["t_loop"] == 10
    with pytest.raises(SystemExit) as exc:  # argparse's usage error
        main(["tune-slam", "--sequence", str(seq_dir), "--odometry", "gt-noisy", "--out", str(out), "--c-s", "x"])
    assert exc.value.code == 2
    assert "--c-s" in capsys.readouterr().err
    # --pose as slam's: the epipolar mode needs the network odometry, one line, exit 2, nothing written
    out.unlink()
    rc = main(["tune-slam", "--sequence", str(seq_dir), "--odometry", "gt-noisy", "--out", str(out), "--pose", "epipolar"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--pose epipolar" in err[0] and not out.exists()


def test_tune_cli_defaults_match_the_search_space():
    from deepslam.commands import tune_slam
    from deepslam.slam.tune import SearchSpace

    d = SearchSpace()
    assert tune_slam._floats(tune_slam.DEFAULT_C_S) == d.c_s
    assert tune_slam._floats(tune_slam.DEFAULT_C_R) == d.c_r
    assert tune_slam._ints(tune_slam.DEFAULT_T_LOOP) == d.t_loop


def test_slam_cli_corrupt_image_read_in_the_relocalization_thread(seq_dir, tmp_path, capsys):
    """The keyframes' features are extracted in a second thread: a truncated image there still ends
    with one line naming the file, exit status 2 and no trajectory written."""
    import shutil

    bad = tmp_path / "seq"
    shutil.copytree(seq_dir, bad)
    png = sorted((bad / "rgb").glob("*.png"))[6]  # a keyframe (every 3rd frame by default)
    png.write_bytes(png.read_bytes()[:100])
    out = tmp_path / "t.txt"
    rc = main(["slam", "--sequence", str(bad), "--odometry", "gt-noisy", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and png.name in err[0]
    assert not out.exists()


def test_keyframe_stride_flags_default_to_the_pipelines():
    from deepslam.cli import build_parser
    from deepslam.slam.pipeline import PipelineConfig

    for command in ("slam", "tune-slam"):
        parsed, _ = build_parser().parse_known_args([command, "--sequence", "s", "--out", "o"])
        assert parsed.keyframe_stride == PipelineConfig().keyframe_stride == 3, command
