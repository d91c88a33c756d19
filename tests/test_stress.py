"""`deepslam stress`: the rigid-scene failure measured in simulation (tiny sweeps: 6 frames, 96 px wide)."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from deepslam.cli import main
from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.core.dynamic import dynamic_fraction
from deepslam.core.errors import InputError
from deepslam.slam.compare import plugin_key
from deepslam.slam.rigid_fit import RigidFitOdometry
from deepslam.studies.stress import Setting, StressConfig, run_stress, setting_scene

# room seed 1: the table's flags fill ~6 % of the first frames and 16 flying boxes ~3 %
TINY = StressConfig(scene="room", seed=1, frames=6, width=96, objects=(0, 16), object_sizes=(1.0,), size_objects=16,
                    deform_amplitudes_m=(0.1, 0.3), odometry="rigid-fit", validation_frames=5, combined=False)


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    out = tmp_path_factory.mktemp("stress")
    report = run_stress(TINY, out, progress=False)
    return out, report


def _rows(report):
    return {r["setting"]: r for r in report["rows"]}


def test_static_flow_exact_dynamic_flow_error_grows(study):
    _, report = study
    rows = _rows(report)
    assert set(rows) == {"k0_s1_a0", "k16_s1_a0", "k0_s1_a0.1", "k0_s1_a0.3"}
    for r in rows.values():  # the control: the rigid synthesis is exact wherever the scene is static
        assert r["epe_static_px"] < 1e-3
    static = rows["k0_s1_a0"]
    assert static["dynamic_pct"] == 0 and static["epe_dynamic_px"] is None and static["dynamic_pixels_compared"] == 0
    movers = rows["k16_s1_a0"]
    assert movers["dynamic_pct"] > 0.5 and movers["epe_dynamic_px"] > 100 * movers["epe_static_px"]
    assert movers["epe_dynamic_px"] > 0.1
    # flags: same pixels, three times the amplitude -> clearly larger error (flow error ~ amplitude)
    a1, a3 = rows["k0_s1_a0.1"], rows["k0_s1_a0.3"]
    assert a1["dynamic_pct"] > 1 and abs(a3["dynamic_pct"] - a1["dynamic_pct"]) < 0.5 * a1["dynamic_pct"]
    assert a3["epe_dynamic_px"] > 2.0 * a1["epe_dynamic_px"] > 0


def test_rigid_fit_vo_exact_on_static_scene_and_biased_by_movers(study):
    _, report = study
    rows = _rows(report)
    assert report["odometry"] == "rigid-fit"
    # exact flow + depth of a rigid scene: the least-squares fit recovers the motion
    assert rows["k0_s1_a0"]["vo_ate_gt_m"] < 1e-4
    assert rows["k0_s1_a0"]["vo_rpe_r_gt_deg"] < 1e-3
    # the movers' pixels pull the same fit off: the rigid assumption failing, directly
    assert rows["k16_s1_a0"]["vo_ate_gt_m"] > 10 * max(rows["k0_s1_a0"]["vo_ate_gt_m"], 1e-6)
    for r in rows.values():
        for k in ("vo_ate_dis_m", "slam_ate_gt_m", "slam_ate_dis_m", "vo_rpe_t_dis_m"):
            assert r[k] is not None and np.isfinite(r[k])


def test_outputs_exist_and_parse(study):
    out, report = study
    data = json.loads((out / "stress.json").read_text())
    assert data["format"] == "deepslam-stress-v1" and len(data["rows"]) == 4
    assert [r["dynamic_pct"] for r in data["rows"]] == sorted(r["dynamic_pct"] for r in data["rows"])
    assert any("no loop closure" in n for n in data["notes"])  # 6 frames < T_loop
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["config"]["scene"] == "room" and cfg["config"]["frames"] == 6 and len(cfg["settings"]) == 4
    md = (out / "stress.md").read_text()
    assert "**Conclusion.**" in md and "k16_s1_a0" in md and md.count("\n| k") == 4
    assert data["conclusion"]["worst"] in ("k16_s1_a0", "k0_s1_a0.1", "k0_s1_a0.3")
    assert f"{data['conclusion']['worst_epe_dynamic_px']:.3g} px" in data["conclusion"]["text"]
    for name in ("stress_flow_epe.png", "stress_vo_ate.png", "stress_vo_rpe.png", "stress_slam_ate.png"):
        img = cv2.imread(str(out / name))
        assert img is not None and img.shape[0] > 100
    assert len(list((out / "settings").glob("*.json"))) == 4
    assert not (out / "sequences").exists()  # rendered sequences are removed unless kept


def test_html_report_shows_the_table_the_conclusion_and_the_plots(study):
    out, report = study
    page = (out / "report.html").read_text()
    assert page.startswith("<!DOCTYPE html>") and page.rstrip().endswith("</html>")
    assert page.count("<table>") == 1 and page.count("<tr><td>") == 4  # one row per setting, no side-by-side
    for r in report["rows"]:
        assert f"<tr><td>{r['setting']}</td><td>{r['axis']}</td><td>{r['dynamic_pct']:.2f}</td>" in page
    assert "<strong>Conclusion.</strong>" in page and f"{report['conclusion']['worst_epe_dynamic_px']:.3g} px" in page
    for name in ("stress_flow_epe.png", "stress_vo_ate.png", "stress_vo_rpe.png", "stress_slam_ate.png"):
        assert f'<a href="{name}"><img src="{name}"' in page and (out / name).is_file()
    assert "<script" not in page and "http" not in page  # plain, self-contained beside its plots


def test_resume_reuses_setting_results(study, tmp_path):
    out, report = study
    again = run_stress(TINY, out, resume=True, progress=False)
    assert again["rows"] == report["rows"]


def test_bad_input_one_line_exit_2(tmp_path, capsys):
    out = tmp_path / "never"
    cases = [(["--scene", "moon"], "unknown scene"), (["--objects", ""], "empty"), (["--deform", "-0.1"], "non-negative"),
             (["--deform", "0.2,x"], "not a number"), (["--object-size", "0"], "object size"),
             (["--objects", "1,2.5"], "not an integer"), (["--frames", "2"], "frames"),
             (["--odometry", "oracle"], "unknown plugin 'oracle'"), (["--deform", "0.5"], "at most"),
             (["--model-cons", str(tmp_path / "missing.pt")], "missing.pt"),
             (["--odometry", "rigid-fit", "--model-cons", "kitti"], "rigid-fit uses no model"),
             (["--odometry-command", "prog {sequence}"], "needs an {out} placeholder"),
             (["--odometry-command", "prog 'unbalanced {out}"], "cannot be split"),
             (["--odometry-command", "a {out}", "--odometry-command", "a {out}"], "listed twice"),
             (["--odometry-command", "a {out}", "--command-timeout", "0"], "timeout")]
    for extra, what in cases:
        rc = main(["stress", "--out", str(out), *extra])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2, extra
        assert len(err) == 1 and what in err[0], (extra, err)
    assert not out.exists()


def test_settings_one_factor_at_a_time():
    s = StressConfig(objects=(0, 4), object_sizes=(0.5, 1.0), size_objects=4, deform_amplitudes_m=(0.0, 0.2),
                     combined=True).validate().settings()
    assert [(x.name, x.axis) for x in s] == [("k0_s1_a0", "objects"), ("k4_s1_a0", "objects"), ("k4_s0.5_a0", "size"),
                                            ("k0_s1_a0.2", "deform"), ("k4_s1_a0.2", "combined")]
    with pytest.raises(InputError):
        StressConfig(deform_amplitudes_m=()).validate()


def test_scaled_movers_drive_where_unscaled_ones_do():
    """A size setting changes the movers' size only: same placement as the unscaled scene in the simulator."""
    from deepslam.sim import Simulator

    cfg = StressConfig(scene="street", frames=6, width=96, objects=(3,))
    plain_cfg, plain_scene = setting_scene(cfg, Setting("a", "objects", 3, 1.0, 0.0))
    big_cfg, big_scene = setting_scene(cfg, Setting("b", "size", 3, 2.0, 0.0))
    with Simulator(plain_cfg) as a, Simulator(big_cfg, scene=big_scene) as b:
        movers_a = [x for x in a.scene.bodies if x.kind == "rigid"]
        movers_b = [x for x in b.scene.bodies if x.kind == "rigid"]
        assert len(movers_a) == len(movers_b) == 3
        times = np.linspace(0.0, 0.6, 4)
        for ma, mb in zip(movers_a, movers_b):
            np.testing.assert_allclose(mb.motion.world_from_body(times), ma.motion.world_from_body(times), atol=1e-12)
            np.testing.assert_allclose(mb.mesh.vertices, 2.0 * ma.mesh.vertices)


def test_rigid_fit_recovers_motion_and_is_pulled_by_a_mover():
    from deepslam.gen.flow import synthesize

    cam = PinholeCamera(96, 64, 80.0, 80.0, 47.5, 31.5)
    v, u = np.mgrid[0:64, 0:96]
    depth = (4.0 + 0.03 * u + 0.02 * v).astype(np.float32)  # a slanted plane
    depth[20:40, 30:50] = 2.5  # and a box in front of it
    motion = se3.from_euler6(np.array([0.01, -0.02, 0.005, 0.1, -0.05, 0.4]))
    flow, valid = (x.numpy() for x in synthesize(depth, cam, motion))
    flow[~valid] = np.nan
    fit = RigidFitOdometry(None)
    mean6, std6 = fit.fit(depth, flow, cam)
    np.testing.assert_allclose(mean6, se3.to_euler6(motion), atol=1e-5)
    assert (std6 > 0).all()
    # the box moves on its own (2 px right): a plain least-squares fit absorbs part of it
    flow[20:40, 30:50, 0] += 2.0
    biased, _ = fit.fit(depth, flow, cam)
    assert np.abs(biased - se3.to_euler6(motion)).max() > 1e-3


def test_falls_back_to_rigid_fit_with_a_note_when_no_model_is_shipped(tmp_path, monkeypatch):
    from deepslam.studies.stress import make_odometries
    from deepslam.vo.modelfiles import models

    monkeypatch.setattr(models, "models_dir", lambda: tmp_path)  # an empty models/ folder
    odo = make_odometries(StressConfig())
    assert odo.kind == "rigid-fit" and "unavailable" in odo.note and "kitti_cons.safetensors" in odo.note
    assert set(odo.cons) == {"gt", "dis"} and isinstance(odo.loops, RigidFitOdometry)


def test_dynamic_fraction_pools_the_pixels_of_all_masks():
    a, b = np.zeros((2, 4), np.uint8), np.zeros((4, 4), np.uint16)
    a[0, :3], b[1:, 1] = 1, 7
    assert dynamic_fraction(a) == 3 / 8 and dynamic_fraction(a, b) == 6 / 24
    assert dynamic_fraction() == 0.0 and dynamic_fraction(a, None) == 0.0  # no mask: nothing known to move


def test_external_odometry_command_is_compared_side_by_side(tmp_path, capsys):
    """An external program (here: one answering with the ground truth, KITTI layout) is one more odometry
    of the study: it runs without a shell on every rendered sequence, in the table, the JSON and the page."""
    script = tmp_path / "gt odometry.py"  # a space in the path: still one argument
    script.write_text("import shutil, sys\nshutil.copy(sys.argv[1] + '/poses.txt', sys.argv[2])\n")
    out = tmp_path / "stress"
    rc = main(["stress", "--out", str(out), "--scene", "room", "--seed", "1", "--frames", "6", "--width", "96",
               "--objects", "0,16", "--object-size", "1", "--size-objects", "0", "--deform", "0", "--no-combined",
               "--odometry", "rigid-fit", "--odometry-command", f"{sys.executable} '{script}' {{sequence}} {{out}}",
               "--json", "--quiet"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    printed = json.loads(cap.out)
    entries = {(e["name"], e["odometry_key"]): e for e in printed["settings"]}
    exe = Path(sys.executable).name
    key = plugin_key(exe)
    assert {k for _, k in entries} == {"gt", "dis", key}
    for name in ("k0_s1_a0", "k16_s1_a0"):
        mine = entries[(name, key)]
        assert mine["odometry"] == f"{exe} (plug-in)"
        assert mine["vo_ate_m"] < 1e-6 and mine["slam_ate_m"] < 1e-6  # the ground truth, chained back
    # the movers pull the rigid fit, not the program that reads the true poses
    assert entries[("k16_s1_a0", "gt")]["vo_ate_m"] > 100 * entries[("k16_s1_a0", key)]["vo_ate_m"]
    report = json.loads((out / "stress.json").read_text())
    assert report["config"]["commands"] == [f"{sys.executable} '{script}' {{sequence}} {{out}}"]
    assert report["plugins"] == {key: exe}
    md = (out / "stress.md").read_text()
    assert "**Side by side**" in md and f"{exe} (plug-in)" in md
    page = (out / "report.html").read_text()
    assert page.count("<table>") == 2 and f"<th>{exe} (plug-in)</th>" in page
