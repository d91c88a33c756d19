"""Plug-in odometry (MODULE:FACTORY, entry points, external commands) in vo and slam, and its refusals."""
from __future__ import annotations

import re
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from deepslam.core import trajio
from deepslam.core.errors import InputError
from deepslam.core.readers import open_sequence

PLUGIN = '''
import numpy as np
from deepslam.core import se3

class GtOdometry:
    """A user's odometry: the ground truth's relative motions."""
    name = "user-gt"
    def predict(self, seq, pairs):
        p = np.asarray(pairs).reshape(-1, 2)
        w = seq.gt.world_from_cam
        return se3.to_euler6(se3.relative(w[p[:, 1]], w[p[:, 0]])).reshape(-1, 6), np.full((len(p), 6), 0.01)

def make():
    return GtOdometry()

class Bad:
    name = "bad"
    def __init__(self, kind): self.kind = kind
    def predict(self, seq, pairs):
        n = len(pairs)
        if self.kind == "shape":
            return np.zeros((n, 5)), np.ones((n, 5))
        if self.kind == "nan":
            m = np.zeros((n, 6)); m[1, 2] = np.nan
            return m, np.ones((n, 6))
        if self.kind == "std":
            return np.zeros((n, 6)), np.zeros((n, 6))
        raise RuntimeError("my model crashed")

def make_shape(): return Bad("shape")
def make_nan(): return Bad("nan")
def make_std(): return Bad("std")
def make_raise(): return Bad("raise")
class MyFlow:
    """A user's flow estimator: DIS fast under another name."""
    name = "my-dis"
    def __init__(self):
        from deepslam.flow.registry import make
        self.inner = make("dis", preset="fast")
    def estimate(self, a, b): return self.inner.estimate(a, b)
    def pair_flow(self, seq, i, j): return self.inner.pair_flow(seq, i, j)

def make_flow(): return MyFlow()
def make_nothing(): return 42
def make_failing(): raise ValueError("no weights here")
NOT_CALLABLE = 3
'''

WRITER = '''
import shutil, sys
from pathlib import Path
seq, out = Path(sys.argv[1]), Path(sys.argv[2])
mode = sys.argv[3] if len(sys.argv) > 3 else "ok"
if mode == "fail":
    print("segmentation fault (core dumped)", file=sys.stderr); sys.exit(3)
if mode == "nothing":
    sys.exit(0)
lines = (seq / "poses.txt").read_text().splitlines()
if mode == "short":
    lines = lines[:-2]
out.write_text("\\n".join(lines) + "\\n")
'''


@pytest.fixture(scope="module")
def plugin_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("userpkg")
    (d / "user_vo.py").write_text(textwrap.dedent(PLUGIN))
    (d / "writer.py").write_text(textwrap.dedent(WRITER))
    sys.path.insert(0, str(d))
    yield d
    sys.path.remove(str(d))


@pytest.fixture(scope="module")
def seq_dir(tmp_path_factory) -> Path:
    from deepslam.cli import main

    out = tmp_path_factory.mktemp("plug") / "street"
    assert main(["render", "--scene", "street", "--frames", "8", "--width", "160", "--seed", "4", "--out", str(out),
                 "--quiet"]) == 0
    return out


def _main(argv, capsys):
    from deepslam.cli import main

    rc = main([str(a) for a in argv])
    return rc, capsys.readouterr()


def test_python_plugin_in_vo_gives_the_ground_truth_back(plugin_dir, seq_dir, tmp_path, capsys):
    rc, cap = _main(["vo", "--sequence", seq_dir, "--odometry", "user_vo:make", "--out", tmp_path / "t.txt"], capsys)
    assert rc == 0, cap.err
    est = trajio.read_trajectory(tmp_path / "t.txt")
    gt = open_sequence(seq_dir).gt
    rel = np.linalg.inv(gt.world_from_cam[0]) @ gt.world_from_cam
    np.testing.assert_allclose(est.world_from_cam, rel, atol=1e-9)
    assert "ATE 0.000 m" in cap.out


def test_external_command_in_vo_and_slam(plugin_dir, seq_dir, tmp_path, capsys):
    cmd = f"{sys.executable} {plugin_dir / 'writer.py'} {{sequence}} {{out}}"
    rc, cap = _main(["vo", "--sequence", seq_dir, "--odometry-command", cmd, "--out", tmp_path / "t.txt"], capsys)
    assert rc == 0, cap.err
    assert "ATE 0.000 m" in cap.out
    rc, cap = _main(["slam", "--sequence", seq_dir, "--odometry-command", cmd, "--out", tmp_path / "s.txt"], capsys)
    assert rc == 0, cap.err
    assert len(trajio.read_trajectory(tmp_path / "s.txt")) == 8


def test_entry_point_names_resolve():
    from deepslam.slam import plugins
    from deepslam.slam.classical import PnPOdometry

    assert isinstance(plugins.load_odometry("pnp").inner, PnPOdometry)
    assert isinstance(plugins.load_odometry("deepslam.slam.classical:make_pnp").inner, PnPOdometry)
    from deepslam.vo.odometry import PaperNetwork

    assert isinstance(plugins.load_odometry("network").inner, PaperNetwork)


def test_the_papers_network_plugin_is_the_shipped_model_read_with_its_own_pose(seq_dir):
    from deepslam.vo.modelfiles import models
    from deepslam.vo.odometry import PaperNetwork, model_odometry

    seq = open_sequence(seq_dir)
    pairs = [(0, 1), (1, 2), (2, 3)]
    mean6, std6 = PaperNetwork().predict(seq, pairs)
    path, shipped = models.locate(None, seq, "cons", "dis")
    own_mean6, own_std6 = model_odometry(path, "dis", shipped, pose="net").predict(seq, pairs)
    np.testing.assert_array_equal(mean6, own_mean6)
    np.testing.assert_array_equal(std6, own_std6)


def test_classical_pnp_baseline_with_depth_is_accurate(seq_dir):
    from deepslam.slam.classical import PnPOdometry
    from deepslam.testing import assert_relative_motion_close

    seq = open_sequence(seq_dir)
    pairs = [(i, i + 1) for i in range(len(seq) - 1)]
    mean6, std6 = PnPOdometry().predict(seq, pairs)
    from deepslam.core.se3 import chain_euler6

    gt = np.linalg.inv(seq.gt.world_from_cam[0]) @ seq.gt.world_from_cam
    assert_relative_motion_close(gt, chain_euler6(mean6), trans_m=0.05, rot_deg=0.3)
    assert (std6 > 0).all()


@pytest.mark.parametrize("spec,what", [
    ("no_such_module:make", "cannot import no_such_module"),
    ("user_vo:missing", "has no attribute 'missing'"),
    ("user_vo:NOT_CALLABLE", "is not callable"),
    ("user_vo:make_nothing", "no predict(seq, pairs) method"),
    ("user_vo:make_failing", "the factory failed (ValueError: no weights here)"),
    ("user_vo:make_shape", "mean6 has shape"),
    ("user_vo:make_nan", "not finite for pair (1, 2)"),
    ("user_vo:make_std", "std6 must be > 0"),
    ("user_vo:make_raise", "predict failed (RuntimeError: my model crashed)"),
    ("nosuchname", "unknown plugin 'nosuchname'"),
])
def test_bad_python_plugin_is_one_line_exit_2(spec, what, plugin_dir, seq_dir, tmp_path, capsys):
    rc, cap = _main(["vo", "--sequence", seq_dir, "--odometry", spec, "--out", tmp_path / "t.txt"], capsys)
    lines = cap.err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and what in lines[0] and "Traceback" not in cap.err, cap.err
    assert not (tmp_path / "t.txt").exists()


@pytest.mark.parametrize("mode,what", [
    ("fail", "failed with exit status 3: segmentation fault (core dumped)"),
    ("nothing", "wrote no trajectory"),
    ("short", "6 poses for a 8-frame sequence"),
])
def test_bad_command_is_one_line_exit_2(mode, what, plugin_dir, seq_dir, tmp_path, capsys):
    cmd = f"{sys.executable} {plugin_dir / 'writer.py'} {{sequence}} {{out}} {mode}"
    for command in ("vo", "slam"):
        rc, cap = _main([command, "--sequence", seq_dir, "--odometry-command", cmd, "--out", tmp_path / "t.txt"], capsys)
        lines = cap.err.strip().splitlines()
        assert rc == 2 and len(lines) == 1 and what in lines[0], (command, cap.err)


@pytest.mark.slow
def test_stress_compares_the_network_and_the_classical_plugin_side_by_side(tmp_path, capsys):
    import json

    out = tmp_path / "stress"
    rc, cap = _main(["stress", "--quick", "--frames", "40", "--objects", "0,8", "--deform", "0", "--no-loops",
                     "--size-objects", "0", "--odometry", "model", "--odometry", "pnp", "--out", out, "--json"], capsys)
    assert rc == 0, cap.err
    doc = json.loads(cap.out.strip().splitlines()[-1])
    entries = doc["settings"]
    names = {e["name"] for e in entries}
    assert names == {"k0_s1_a0", "k8_s1_a0"}
    for name in names:
        odos = {e["odometry_key"] for e in entries if e["name"] == name}
        assert odos == {"gt", "dis", "pnp-sift"}
    for e in entries:
        assert set(e) >= {"name", "odometry", "dynamic_fraction", "flow_epe_dynamic_px", "vo_ate_m", "slam_ate_m"}
        assert e["vo_ate_m"] >= 0 and 0 <= e["dynamic_fraction"] < 1
    static_pnp = next(e for e in entries if e["name"] == "k0_s1_a0" and e["odometry_key"] == "pnp-sift")
    assert static_pnp["vo_ate_m"] < 0.5  # SIFT + PnP with exact depth on a static street
    md = (out / "stress.md").read_text()
    assert "Side by side" in md and "pnp-sift (plug-in)" in md
    assert (out / "stress_vo_ate.png").stat().st_size > 0


def test_vo_and_train_json(seq_dir, plugin_dir, tmp_path, capsys):
    import json

    rc, cap = _main(["vo", "--sequence", seq_dir, "--odometry", "user_vo:make", "--out", tmp_path / "t.txt", "--json"],
                    capsys)
    assert rc == 0, cap.err
    doc = json.loads(cap.out)
    assert doc["poses"] == 8 and doc["metrics"]["ate_m"] < 1e-9 and doc["metrics"]["path_length_ratio"] == pytest.approx(1)
    rc, cap = _main(["train", "--mode", "synthetic", "--toy", "96", "--net", "tiny", "--batch", "16", "--max-epochs", "1",
                     "--nll-epochs", "1", "--bf16", "off", "--out", tmp_path / "m", "--json"], capsys)
    assert rc == 0, cap.err
    doc = json.loads(cap.out)
    assert doc["stop_reason"] == "max_epochs" and doc["epochs"] == 1 and doc["model"].endswith("model.safetensors")


def test_flow_plugin_in_vo(plugin_dir, seq_dir, tmp_path, capsys):
    import json

    rc, cap = _main(["vo", "--sequence", seq_dir, "--flow", "user_vo:make_flow", "--out", tmp_path / "t.txt"], capsys)
    assert rc == 0, cap.err
    assert json.loads((tmp_path / "t.config.json").read_text())["flow"] == "my-dis"
    rc, cap = _main(["vo", "--sequence", seq_dir, "--flow", "user_vo:make_nothing", "--out", tmp_path / "u.txt"], capsys)
    lines = cap.err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and "no estimate or pair_flow method" in lines[0], cap.err
    rc, cap = _main(["vo", "--sequence", seq_dir, "--flow", "nosuchflow", "--out", tmp_path / "v.txt"], capsys)
    assert rc == 2 and "unknown flow estimator 'nosuchflow'" in cap.err



def _slam_odometries(seq_dir, argv: list, overrides: dict):
    """The odometries ``deepslam slam`` builds from its command line (``overrides``: dest -> value of --dis-* flags)."""
    from deepslam.cli import build_parser
    from deepslam.commands import _odometry_flags
    from deepslam.slam.plugins import odometries

    flags = [x for dest, v in overrides.items() for x in (f"--{dest.replace('_', '-')}", str(v))]
    args = build_parser().parse_args(["slam", "--sequence", str(seq_dir), "--out", "unused.txt", "--device", "cpu",
                                      *map(str, argv), *flags])
    return odometries(_odometry_flags.options(args), open_sequence(seq_dir))


def test_slam_gives_each_model_the_flow_it_was_trained_on(seq_dir, tmp_path):
    """NN_cons trained on DIS with textureless pixels left out, NN_loops on plain DIS: slam sets DIS up
    per model (two estimators); models that agree share one estimator."""
    from deepslam.slam.plugins import OdometryOptions, odometries
    from deepslam.vo.modelfiles.modelio import save_model
    from deepslam.vo.net import FlowPoseNet, NetConfig

    net = FlowPoseNet(NetConfig(input_height=24, input_width=80, filters=8, hidden_units=16))
    tex, plain = tmp_path / "tex.safetensors", tmp_path / "plain.safetensors"
    save_model(tex, net, {"flow": {"estimator": "dis", "options": {"preset": "fast", "min_texture": 0.5}}})
    save_model(plain, net, {"flow": {"estimator": "dis", "options": {"preset": "medium", "min_texture": 0.0}}})
    seq = open_sequence(seq_dir)
    cons, loops = odometries(OdometryOptions(model_cons=str(tex), model_loops=str(plain)), seq)
    assert cons.flow_estimator.name == "dis-fast-tex0.5" and loops.flow_estimator.name == "dis-medium"
    cons, loops = odometries(OdometryOptions(model_cons=str(tex), model_loops=str(tex)), seq)
    assert cons.flow_estimator is loops.flow_estimator


@pytest.mark.parametrize("overrides, cons_name, loops_name, shared", [
    ({}, "dis-fast-tex0.5", "dis-medium", False),  # nothing given: each model's record
    ({"dis_patch_stride": 4}, "dis-fast-tex0.5-s4", "dis-medium-s4", False),  # given: for both models
    ({"dis_preset": "medium", "dis_min_texture": 0.0}, "dis-medium", "dis-medium", True),  # now one set-up
])
def test_slam_dis_flags_override_both_models_records(seq_dir, tmp_path, overrides, cons_name, loops_name, shared):
    """``slam --dis-*`` (as ``vo --dis-*``): a flag given sets DIS up so for NN_cons and NN_loops alike, the
    options not given stay each model's recorded ones; models whose set-ups then agree share one estimator."""
    from deepslam.vo.modelfiles.modelio import save_model
    from deepslam.vo.net import FlowPoseNet, NetConfig

    net = FlowPoseNet(NetConfig(input_height=24, input_width=80, filters=8, hidden_units=16))
    tex, plain = tmp_path / "tex.safetensors", tmp_path / "plain.safetensors"
    save_model(tex, net, {"flow": {"estimator": "dis", "options": {"preset": "fast", "min_texture": 0.5}}})
    save_model(plain, net, {"flow": {"estimator": "dis", "options": {"preset": "medium", "min_texture": 0.0}}})
    cons, loops = _slam_odometries(seq_dir, ["--model-cons", tex, "--model-loops", plain], overrides)
    assert (cons.flow_estimator.name, loops.flow_estimator.name) == (cons_name, loops_name)
    assert (cons.flow_estimator is loops.flow_estimator) == shared


@pytest.mark.parametrize("flow, overrides, message", [
    ("dis", {"dis_patch_stride": 9}, "patch_stride"),  # larger than DIS's 8-pixel patch
    ("learned", {"dis_patch_stride": 4}, "--dis-patch-stride applies to DIS flow only"),
])
def test_slam_dis_flags_refuse_what_dis_cannot_take(seq_dir, tmp_path, flow, overrides, message):
    from deepslam.core.errors import InputError
    from deepslam.vo.modelfiles.modelio import save_model
    from deepslam.vo.net import FlowPoseNet, NetConfig

    model = tmp_path / "m.safetensors"
    save_model(model, FlowPoseNet(NetConfig(input_height=24, input_width=80, filters=8, hidden_units=16)),
               {"flow": {"estimator": "dis", "options": {"preset": "medium", "min_texture": 0.0}}})
    with pytest.raises(InputError, match=message):
        _slam_odometries(seq_dir, ["--model-cons", model, "--model-loops", model, "--flow", flow], overrides)


def test_model_odometry_takes_flow_options_over_the_record(tmp_path):
    """``vo.odometry.model_odometry(..., flow_options=...)`` (the benches' stride-4 rows): the given options over the
    file's record, the rest of the record kept; none given: the record alone."""
    from deepslam.vo.modelfiles.modelio import save_model
    from deepslam.vo.net import FlowPoseNet, NetConfig
    from deepslam.vo.odometry import model_odometry

    path = tmp_path / "m.safetensors"
    save_model(path, FlowPoseNet(NetConfig(input_height=24, input_width=80, filters=8, hidden_units=16)),
               {"flow": {"estimator": "dis", "options": {"preset": "fast", "min_texture": 0.5}}})
    assert model_odometry(path, "dis").flow_estimator.name == "dis-fast-tex0.5"
    assert model_odometry(path, "dis", flow_options={"patch_stride": 4}).flow_estimator.name == "dis-fast-tex0.5-s4"


@pytest.mark.parametrize("template,argv", [
    ("run {sequence} {out}", ["run", "/d/my seq", "/t/o.txt"]),
    ('run "{sequence}" "{out}"', ["run", "/d/my seq", "/t/o.txt"]),  # shell habit: still one argument each
    ("run '{sequence}' --out={out}", ["run", "/d/my seq", "--out=/t/o.txt"]),
    ("awk '{print}' {out}", ["awk", "{print}", "/t/o.txt"]),  # other brace text stays literal
    ("echo {{sequence}} {{}} {out}", ["echo", "{sequence}", "{}", "/t/o.txt"]),
    ('"/opt/my vo/run" {out}', ["/opt/my vo/run", "/t/o.txt"]),
])
def test_command_template_becomes_an_argument_vector(template, argv):
    from deepslam.slam.plugins import command_argv

    assert command_argv(template, sequence="/d/my seq", out="/t/o.txt") == argv


@pytest.mark.parametrize("template,what", [
    ("run {sequence}", "needs an {out} placeholder"),
    ("run {{out}}", "needs an {out} placeholder"),
    ("run '{out}", "cannot be split into arguments"),
    ("   ", "is empty"),
])
def test_bad_command_template_is_refused_before_it_runs(template, what):
    from deepslam.slam.plugins import command_argv

    with pytest.raises(InputError, match=re.escape(what)):
        command_argv(template, sequence="s", out="o")


def test_shell_syntax_in_a_path_is_never_run(plugin_dir, seq_dir, tmp_path, capsys, monkeypatch):
    """A sequence folder whose name holds ``$(...)``, backticks and a space, with the placeholders in double
    quotes as shell habit says: the program gets the path as one argument and nothing in it runs."""
    import shutil

    monkeypatch.chdir(tmp_path)
    odd = tmp_path / "seq $(touch PWNED1) `touch PWNED2`; touch PWNED3"
    shutil.copytree(seq_dir, odd)
    cmd = f'{sys.executable} "{plugin_dir / "writer.py"}" "{{sequence}}" "{{out}}" \'{{print}}\''
    rc, cap = _main(["vo", "--sequence", odd, "--odometry-command", cmd, "--out", tmp_path / "t.txt"], capsys)
    assert rc == 0, cap.err
    assert "ATE 0.000 m" in cap.out
    assert not list(tmp_path.glob("PWNED*")) and not list(odd.glob("PWNED*"))


@pytest.mark.parametrize("cmd,extra,what", [
    ("{py} -c 'import time; time.sleep(30)' {{out}}", ["--command-timeout", "0.5"], "no answer within 0.5 s"),
    ("/no/such/program {{sequence}} {{out}}", [], "/no/such/program: odometry command: no such program"),
    ("{py} {{out}}\"", [], "cannot be split into arguments"),
    ("{py} -c 'open(__import__(\"sys\").argv[1], \"w\").write(\"1 2 x\\n\")' {{out}}", [], "trajectory is unreadable"),
    ("{py} -c 'open(__import__(\"sys\").argv[1], \"w\").write(\"nan \" * 12 + \"\\n\")' {{out}}", [], ""),
])
def test_command_failures_are_one_line_exit_2(cmd, extra, what, seq_dir, tmp_path, capsys):
    cmd = cmd.format(py=sys.executable)
    rc, cap = _main(["vo", "--sequence", seq_dir, "--odometry-command", cmd, *extra, "--out", tmp_path / "t.txt"],
                    capsys)
    lines = cap.err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and what in lines[0] and "Traceback" not in cap.err, cap.err
    assert not (tmp_path / "t.txt").exists()
