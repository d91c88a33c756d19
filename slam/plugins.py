"""Anyone's odometry where deepslam's goes: Python plugins, entry points and external commands.

Three ways to plug an odometry into ``vo``, ``slam``, ``tune-slam`` and ``stress`` (``--odometry``):

- ``MODULE:FACTORY``: ``FACTORY`` is a callable in an importable module returning an object with
  ``name`` and ``predict(seq, pairs) -> (mean6, std6)`` (:class:`deepslam.slam.odometry.Odometry`:
  the paper's vector of ``cam_j_from_cam_i`` per pair (i, j), R = Rz Ry Rx, and its std).
- a NAME registered by an installed package under the entry-point group ``deepslam.odometry``
  (``[project.entry-points."deepslam.odometry"] myvo = "mypkg.vo:make"``), used the same way.
- ``--odometry-command 'CMD {sequence} {out}'`` (:class:`CommandOdometry`): an external program (ORB-SLAM,
  DPVO, a script) that reads the sequence folder and writes a trajectory to ``{out}`` (KITTI or TUM,
  detected); deepslam turns it into relative motions with a fixed std (``DEFAULT_COMMAND_STD6``) or
  the six numbers the program writes to ``{out}.std`` (rad x3, m x3; applied to every pair). No shell
  runs it: the template is split once into arguments (:func:`command_argv`, shell quoting rules) and the
  placeholders are replaced inside each argument, so a path is one argument whatever it holds.

Every answer goes through :func:`checked`, which turns a plugin's failure (an import error, a missing
attribute, an exception, wrong shapes, NaN, a std <= 0) into an InputError naming the plugin.
"""
from __future__ import annotations

import contextlib
import dataclasses
import multiprocessing
import os
import re
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Sequence as SequenceT

import numpy as np

from deepslam.core import se3
from deepslam.core.errors import InputError
from deepslam.core.plugins import ENTRY_POINT_GROUPS, load_factory
from deepslam.core.trajio import read_trajectory_and_format
from deepslam.slam.odometry import GroundTruthOdometry, NoiseConfig, check_prediction
from deepslam.vo.modelfiles import models
from deepslam.vo.pipeline import check_read_width, read_view

ENTRY_POINT_GROUP = ENTRY_POINT_GROUPS["odometry"]
"""Entry-point group of odometry plugins (``NAME = "module:factory"``)."""
DEFAULT_COMMAND_STD6 = (0.002, 0.002, 0.002, 0.05, 0.05, 0.05)
"""Std of an external command's relative motions when it writes none (rad x3, m x3)."""
DEFAULT_COMMAND_TIMEOUT_S = 3600.0
"""Seconds an external odometry command may run on one sequence before it is stopped."""
_PLACEHOLDER = re.compile(r"\{\{|\}\}|\{(sequence|out)\}")


def command_argv(template: str, **values: str) -> list[str]:
    """The argument vector of an external command: ``template`` split once by shell quoting rules
    (:func:`shlex.split`; no shell ever runs it), then in each argument ``{sequence}`` and ``{out}``
    replaced by ``values`` as they are (no quoting: each argument reaches the program intact, spaces and
    ``$(...)`` included), ``{{`` and ``}}`` by single braces; any other brace text stays literal
    (``awk '{print}'``).

    Raises:
        InputError: unbalanced quotes, an empty template, or no ``{out}`` placeholder.
    """
    try:
        words = shlex.split(template)
    except ValueError as e:
        raise InputError(None, f"--odometry-command cannot be split into arguments ({e}): {_short(template)}") from None
    if not words:
        raise InputError(None, "--odometry-command is empty")
    if not any(m.group(1) == "out" for w in words for m in _PLACEHOLDER.finditer(w)):
        raise InputError(None, f"--odometry-command needs an {{out}} placeholder: {_short(template)}")

    def sub(m: re.Match) -> str:
        return {"{{": "{", "}}": "}"}.get(m.group(0)) or values[m.group(1)]

    return [_PLACEHOLDER.sub(sub, w) for w in words]


def _short(text: str, n: int = 120) -> str:
    """``text`` for a message: repr'd and cut to ``n`` characters."""
    r = repr(text)
    return r if len(r) <= n else r[:n - 3] + "..."


def call_isolated(fn, label: str, timeout_s: float):
    """``fn()`` run in a forked child process, its answer sent back through a pipe: a Python plug-in's
    ``sys.exit``, ``os._exit``, crash or endless loop cannot end or hang the run, and what it prints goes to
    stderr (the child's stdout is its stderr), never into a command's ``--json`` output. torch runs on one
    thread in the child (a forked child that uses the thread pool its parent started hangs).

    Raises:
        InputError: naming ``label`` when ``fn`` raises (SystemExit included), the child exits without an
            answer (``os._exit``, a signal), or no answer comes within ``timeout_s`` seconds (the child is
            killed).
    """
    ctx = multiprocessing.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)

    def child() -> None:
        os.dup2(2, 1)  # the plug-in's prints go to stderr, whatever writes them
        sys.stdout = sys.stderr
        if "torch" in sys.modules:  # a forked child that uses torch's inherited thread pool hangs: one thread
            sys.modules["torch"].set_num_threads(1)
        try:
            answer = ("ok", fn())
        except InputError as e:
            answer = ("error", e.message())
        except SystemExit as e:
            answer = ("error", f"it called sys.exit({e.code!r})")
        except BaseException as e:  # noqa: BLE001 - a user's plugin: report it, one line
            answer = ("error", f"predict failed ({type(e).__name__}: {e})")
        try:
            send.send(answer)
        except Exception as e:  # noqa: BLE001 - an answer that cannot be pickled
            send.send(("error", f"its answer cannot be sent back ({type(e).__name__}: {e})"))
        sys.stderr.flush()
        os._exit(0)

    proc = ctx.Process(target=child, daemon=True)
    proc.start()
    send.close()
    try:
        if not recv.poll(timeout_s):
            raise InputError(None, f"odometry plugin {label}: no answer within {timeout_s:g} s (--command-timeout)")
        try:
            status, value = recv.recv()
        except EOFError:
            proc.join(5)
            raise InputError(None, f"odometry plugin {label}: its process ended without an answer (exit status "
                                   f"{proc.exitcode}: os._exit, a crash or a signal)") from None
    finally:
        recv.close()
        if proc.is_alive():
            proc.kill()
        proc.join()
    if status != "ok":
        raise InputError(None, f"odometry plugin {label}: {value}")
    return value


class CheckedOdometry:
    """Wraps a plugin odometry: every answer is validated, every failure an InputError naming it.

    ``timeout_s``: a Python plug-in's ``predict`` runs in a forked child (:func:`call_isolated`) with this
    many seconds to answer; None runs it in this process (an external command, already a process of its
    own with its own timeout)."""

    def __init__(self, inner, label: str, timeout_s: float | None = None):
        self.inner = inner
        self.label = label
        self.name = str(getattr(inner, "name", label))
        self.timeout_s = timeout_s

    def predict(self, seq, pairs: SequenceT[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
        try:
            if self.timeout_s is not None:
                mean6, std6 = call_isolated(lambda: self.inner.predict(seq, pairs), self.label, self.timeout_s)
            else:
                mean6, std6 = self.inner.predict(seq, pairs)
        except InputError:
            raise
        except Exception as e:  # noqa: BLE001 - a user's plugin: report it, one line
            raise InputError(None, f"odometry plugin {self.label}: predict failed ({type(e).__name__}: {e})") from None
        plain = [(int(i), int(j)) for i, j in np.asarray(pairs, dtype=np.int64).reshape(-1, 2)]
        try:
            return check_prediction(self.label, plain, mean6, std6)
        except (ValueError, TypeError) as e:
            what = str(e).removeprefix(f"odometry {self.label!r}: ")
            raise InputError(None, f"odometry plugin {self.label}: {what}") from None


def checked(odometry, label: str, timeout_s: float | None = None) -> CheckedOdometry:
    """``odometry`` wrapped by :class:`CheckedOdometry`, after checking it has ``name`` and ``predict``."""
    if not callable(getattr(odometry, "predict", None)):
        raise InputError(None, f"odometry plugin {label}: the factory returned {type(odometry).__name__}, "
                               "which has no predict(seq, pairs) method")
    return CheckedOdometry(odometry, label, timeout_s)


def load_odometry(spec: str, timeout_s: float = DEFAULT_COMMAND_TIMEOUT_S) -> CheckedOdometry:
    """An odometry from ``MODULE:FACTORY`` or an entry-point NAME (the factory is called with no arguments);
    its ``predict`` runs isolated with ``timeout_s`` seconds to answer (:func:`call_isolated`)."""
    factory = load_factory(spec, ENTRY_POINT_GROUP)
    try:
        with contextlib.redirect_stdout(sys.stderr):  # what the factory prints never reaches --json output
            odo = factory()
    except SystemExit as e:
        raise InputError(None, f"odometry plugin {spec}: the factory called sys.exit({e.code!r})") from None
    except Exception as e:  # noqa: BLE001
        raise InputError(None, f"odometry plugin {spec}: the factory failed ({type(e).__name__}: {e})") from None
    return checked(odo, spec, timeout_s)


class CommandOdometry:
    """An external program that writes a trajectory, as an odometry.

    The command template (:func:`command_argv`) gets ``{sequence}`` (the sequence folder) and ``{out}``
    (the trajectory file to write) substituted inside its arguments; it runs without a shell, once per
    sequence, with ``timeout_s`` to answer, and its trajectory is cached. A KITTI-format answer must have
    one pose per frame (matched by index); a TUM answer is matched to the frames by timestamp (nearest
    within ``max_diff_s``). Relative motions of the pairs come from those poses; the std is ``std6``, or
    the six numbers the program writes to ``{out}.std``.
    """

    def __init__(self, template: str, std6=DEFAULT_COMMAND_STD6, max_diff_s: float = 0.02,
                 timeout_s: float = DEFAULT_COMMAND_TIMEOUT_S):
        argv = command_argv(template, sequence="", out="")  # checked before anything runs
        if not timeout_s > 0:
            raise InputError(None, f"the odometry command's timeout must be > 0 s, got {timeout_s}")
        self.template = template
        self.std6 = np.asarray(std6, dtype=np.float64)
        self.max_diff_s = float(max_diff_s)
        self.timeout_s = float(timeout_s)
        self.name = Path(argv[0]).name or "command"
        self._cache: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def _run(self, seq) -> tuple[np.ndarray, np.ndarray]:
        key = str(Path(seq.root).resolve())
        if key in self._cache:
            return self._cache[key]
        with tempfile.TemporaryDirectory(prefix="deepslam-odometry-") as tmp:
            out = Path(tmp) / "trajectory.txt"
            argv = command_argv(self.template, sequence=str(seq.root), out=str(out))
            try:
                r = subprocess.run(argv, shell=False, stdin=subprocess.DEVNULL, capture_output=True, text=True,
                                   errors="replace", timeout=self.timeout_s)
            except subprocess.TimeoutExpired:
                raise InputError(None, f"odometry command {self.name}: no answer within {self.timeout_s:g} s") from None
            except FileNotFoundError:
                raise InputError(argv[0], "odometry command: no such program") from None
            except PermissionError:
                raise InputError(argv[0], "odometry command: not executable") from None
            except OSError as e:
                raise InputError(argv[0], f"odometry command cannot start: {e.strerror or e}") from None
            if r.returncode != 0:
                tail = (r.stderr.strip().splitlines() or [""])[-1][:200]
                raise InputError(None, f"odometry command {self.name} failed with exit status {r.returncode}: {tail}")
            if not out.is_file() or out.stat().st_size == 0:
                raise InputError(None, f"odometry command {self.name} wrote no trajectory to {{out}}")
            try:
                traj, fmt = read_trajectory_and_format(out)
            except InputError as e:
                raise InputError(None, f"odometry command {self.name}: its trajectory is unreadable ({e.message()})") from None
            except (ValueError, UnicodeDecodeError) as e:
                raise InputError(None, f"odometry command {self.name}: its trajectory is unreadable ({e})") from None
            std_file = Path(f"{out}.std")
            std6 = self.std6
            if std_file.is_file():
                try:
                    std6 = np.array([float(x) for x in std_file.read_text().split()], dtype=np.float64)
                except (ValueError, UnicodeDecodeError):
                    raise InputError(None, f"odometry command {self.name}: {{out}}.std is not six numbers") from None
                if std6.shape != (6,) or not (np.isfinite(std6).all() and (std6 > 0).all()):
                    raise InputError(None, f"odometry command {self.name}: {{out}}.std must hold six positive numbers")
        poses = self._per_frame(seq, traj, fmt)
        if not np.isfinite(poses).all():
            raise InputError(None, f"odometry command {self.name}: its trajectory holds non-finite poses")
        self._cache[key] = (poses, std6)
        return poses, std6

    def _per_frame(self, seq, traj, fmt: str) -> np.ndarray:
        n = len(seq)
        if traj.timestamps_s is None or seq.timestamps_s is None:
            if len(traj) != n:
                raise InputError(None, f"odometry command {self.name}: {len(traj)} poses for a {n}-frame sequence "
                                       f"({fmt}, matched by index)")
            return traj.world_from_cam
        t, ts = np.asarray(traj.timestamps_s), np.asarray(seq.timestamps_s)
        idx = np.searchsorted(t, ts)
        lo, hi = np.clip(idx - 1, 0, len(t) - 1), np.clip(idx, 0, len(t) - 1)
        k = np.where(np.abs(t[lo] - ts) <= np.abs(t[hi] - ts), lo, hi)
        gap = np.abs(t[k] - seq.timestamps_s)
        if (gap > self.max_diff_s).any():
            bad = int(np.flatnonzero(gap > self.max_diff_s)[0])
            raise InputError(None, f"odometry command {self.name}: no pose within {self.max_diff_s} s of frame {bad} "
                                   f"(t = {seq.timestamps_s[bad]:.3f} s)")
        return traj.world_from_cam[k]

    def predict(self, seq, pairs: SequenceT[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
        poses, std6 = self._run(seq)
        p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        mean6 = se3.to_euler6(se3.relative(poses[p[:, 1]], poses[p[:, 0]])).reshape(-1, 6)
        return mean6, np.tile(std6, (len(p), 1))


def from_options(odometry: str | None, command: str | None,
                 timeout_s: float = DEFAULT_COMMAND_TIMEOUT_S) -> CheckedOdometry | None:
    """The plug-in odometry the ``--odometry`` / ``--odometry-command`` (``--command-timeout``) flags name,
    or None."""
    if odometry and command:
        raise InputError(None, "give --odometry or --odometry-command, not both")
    if command:
        return command_odometry(command, timeout_s=timeout_s)
    if odometry:
        return load_odometry(odometry, timeout_s)
    return None


def command_odometry(template: str, **kwargs) -> CheckedOdometry:
    """:class:`CommandOdometry` wrapped by :func:`checked`."""
    odo = CommandOdometry(template, **kwargs)
    return checked(odo, f"command {odo.name}")


@dataclasses.dataclass(frozen=True)
class OdometryOptions:
    """Which odometries :func:`odometries` builds for SLAM (the options of ``slam`` and ``tune-slam``)."""

    odometry: str = "model"
    """``model`` (the network), ``gt-noisy`` (ground truth with noise: tests, benches) or a plug-in spec."""
    odometry_loops: str | None = None
    """Loop-pair plug-in spec; None: the consecutive plug-in, or NN_loops with the network."""
    odometry_command: str | None = None
    """An external program's template (``'CMD {sequence} {out}'``) instead of ``odometry``."""
    command_timeout_s: float = DEFAULT_COMMAND_TIMEOUT_S
    """Seconds a command or a Python plug-in's predict may run on a sequence."""
    model_cons: str | None = None
    """NN_cons model file or shipped name; None: the shipped one of the sequence's camera kind."""
    model_loops: str | None = None
    """NN_loops model file or shipped name; None: the shipped one."""
    flow: str = "dis"
    """Flow estimator of the networks."""
    flow_options: tuple[tuple[str, object], ...] = ()
    """Estimator options given (name, value), overriding each model file's record."""
    no_loops: bool = False
    """No loop-pair odometry (odometry only)."""
    pose: str | None = None
    """NN_cons's pose mode (``net``, ``epipolar``); None: the mode its file records."""
    device: str = "cpu"
    """Torch device of the networks (``auto``, ``cpu``, ``cuda[:N]``)."""
    gt_noise: str = "0.002,0.02"
    """``gt-noisy``: 'ROT_STD,T_STD' (rad, m) of the noise per pair."""
    gt_drift: float = 0.002
    """``gt-noisy``: constant yaw bias per pair (rad)."""
    seed: int = 0
    """``gt-noisy``: seed of the noise."""
    progress: bool = False
    """Progress bars of the networks."""
    read_width_px: int = 640
    """With the network odometry: frames narrower than this are read upsampled to it (:func:`network_view`,
    as ``deepslam vo --read-width``); 0: as recorded."""
    std_from_geometry: bool = False
    """With the network odometry: each consecutive pair's std widened by the geometry's disagreement
    (:meth:`vo.infer.VOPredictor.predict_pairs` ``geometry``, ``vo --std-from-geometry``)."""
    centre_principal_point: bool = False
    """With the network odometry: each flow moved so that the camera's principal point lies at the image's centre
    before the networks read it (:func:`flow.estimators.centre_principal_point`, ``vo --centre-principal-point``)."""
    mirror_average: str = models.MIRROR_AVERAGE_DEFAULT
    """With the network odometry: read every flow also mirrored left-right and average the two motions (``on``,
    ``off``, ``auto``: :func:`vo.modelfiles.models.mirror_average`, ``vo --mirror-average``)."""


class UpsampledReading:
    """An odometry (a network's, :meth:`vo.infer.VOPredictor.as_odometry`) that reads frames narrower than
    ``width`` upsampled as the network of the VO model file ``model_path`` on flow ``flow`` reads them
    (:func:`vo.pipeline.read_view`); the rest of it is the odometry's own (its name, estimator, predictor)."""

    def __init__(self, odometry, width: int, model_path, flow: str):
        self.odometry, self.width, self.model_path, self.flow = odometry, int(width), model_path, flow

    def __getattr__(self, name):
        return getattr(self.odometry, name)

    def predict(self, seq, pairs):
        return self.odometry.predict(read_view(seq, self.width, self.model_path, self.flow), pairs)

    def predict_verified(self, seq, pairs):
        return self.odometry.predict_verified(read_view(seq, self.width, self.model_path, self.flow), pairs)


def network_view(opts: OdometryOptions, seq):
    """The sequence as SLAM reads it: with the network odometry, frames narrower than ``opts.read_width_px``
    upsampled as the NN_cons file's network reads them (:func:`vo.pipeline.read_view`; relocalization then sees
    the same frames, its camera scaled alike); with a plug-in, a command or noisy ground truth, ``seq`` itself."""
    if opts.odometry != "model" or opts.odometry_command or not opts.read_width_px:
        return seq
    check_read_width(opts.read_width_px)
    path, _ = models.locate(opts.model_cons, seq, "cons", opts.flow)
    return read_view(seq, opts.read_width_px, path, opts.flow)


def odometries(opts: OdometryOptions, seq):
    """(odo_cons, odo_loops) for SLAM on ``seq`` by ``opts``: noisy ground truth, plug-ins (Python, entry points,
    external commands), or the networks (each model with the flow it was trained on, the options given
    overriding it; NN_cons in its recorded pose mode unless ``pose``). NN_loops runs in the epipolar mode with its
    own distance: the loop pair's fit also tells where its flow broke (:attr:`slam.pipeline.PipelineConfig.loop_check`).
    ``odo_loops`` is None with ``no_loops`` and the network."""
    pose = opts.pose
    if pose == "epipolar" and (opts.odometry != "model" or opts.odometry_command):
        raise InputError(None, f"--pose {pose} needs the network odometry (not a plug-in or gt-noisy)")
    if opts.odometry == "gt-noisy":
        if seq.gt is None:
            raise InputError(seq.root, "--odometry gt-noisy needs a sequence with ground truth")
        try:
            rot, trans = (float(x) for x in opts.gt_noise.split(","))
        except ValueError:
            raise InputError(None, f"--gt-noise must be 'ROT_STD,T_STD', got {opts.gt_noise!r}") from None
        std = (rot, rot, rot, trans, trans, trans)
        cons = GroundTruthOdometry(NoiseConfig(std6=std, bias6=(0, opts.gt_drift, 0, 0, 0, 0), seed=opts.seed),
                                   name="gt-noisy-cons")
        loops = GroundTruthOdometry(NoiseConfig(std6=std, seed=opts.seed + 1), name="gt-noisy-loops")
        return cons, loops
    if opts.odometry_command or opts.odometry != "model":
        if opts.model_cons or opts.model_loops:
            raise InputError(None, "--model-cons/--model-loops and a plug-in odometry exclude each other")
        cons = from_options(None if opts.odometry_command else opts.odometry, opts.odometry_command,
                            opts.command_timeout_s)
        loops = load_odometry(opts.odometry_loops, opts.command_timeout_s) if opts.odometry_loops else cons
        return cons, loops
    # deferred: it imports torch; plug-in and gt-noisy odometries (and vo/slam --help) stay torch-free
    from deepslam.runtime.device import resolve_device
    from deepslam.vo.odometry import model_odometry

    device = resolve_device(opts.device)
    given = dict(opts.flow_options)
    estimators: dict[tuple, object] = {}  # one estimator per set-up: cons and loops share it where they agree

    def odometry(spec, which, pose=None, scale=None, std_from_geometry=False):
        # each model gets the flow as it was trained on it (DIS's preset and texture threshold may differ),
        # with the options given on the command line for both
        path, shipped = models.locate(spec, seq, which, opts.flow)
        recorded = models.recorded_flow_options(path, opts.flow)
        key = tuple(sorted({**recorded, **given}.items()))
        if key not in estimators:
            estimators[key] = models.flow_for_model(opts.flow, path, recorded, **given)
        flow = estimators[key]
        return model_odometry(path, opts.flow, shipped, opts.progress, pose, scale=scale, estimator=flow,
                              std_from_geometry=std_from_geometry, device=device,
                              centre_principal_point=opts.centre_principal_point, mirror_average=opts.mirror_average)

    cons = odometry(opts.model_cons, "cons", pose, std_from_geometry=opts.std_from_geometry)
    # loop pairs: the rotation and direction of the loop pair's flow where its fit serves, NN_loops' distance (a
    # loop pair is no step along a road), and the fit tells where the flow broke (PipelineConfig.loop_check)
    loops = None if opts.no_loops else odometry(opts.model_loops, "loops", "epipolar", "network")
    return cons, loops
