"""A VO model file made ready to run: the one way the commands, SLAM, the studies and the benches build a
predictor or an odometry from a model file or a shipped model's name.

The file is located and its flow estimator set up as it was trained (:mod:`vo.modelfiles.models`, header only,
no torch), then the network is loaded (:class:`vo.infer.VOPredictor`) and, for SLAM and the benches, wrapped as
an odometry with the epipolar settings the file records (:func:`model_odometry`).
"""
from __future__ import annotations

from pathlib import Path

from deepslam.core.errors import InputError
from deepslam.core.kinds import kind_for_sequence
from deepslam.vo.infer import VOPredictor
from deepslam.vo.modelfiles import models


def load_shipped(kind: str, which: str = "cons", flow=None, **kwargs):
    """The shipped :class:`vo.infer.VOPredictor` for ``kind`` / ``which`` (and the flow estimator, see
    :func:`vo.modelfiles.models.shipped_path`); InputError when the file is missing."""
    return load_predictor(models.shipped_path(kind, which, flow), True, **kwargs)


def load_predictor(path: Path, shipped: bool = False, mirror_average: str = models.MIRROR_AVERAGE_DEFAULT,
                   net_pose: bool = True, **kwargs):
    """:class:`vo.infer.VOPredictor` of ``path``; a shipped model is named after its file and, when
    missing, reported with a pointer to models/README.md. ``mirror_average``:
    :data:`vo.modelfiles.models.MIRROR_AVERAGE`'s choice (``vo --mirror-average``), resolved for this file's model
    read with its own pose (``net_pose``) or the epipolar one (:func:`vo.modelfiles.models.mirror_average`)."""
    if shipped:
        if not path.is_file():
            raise InputError(path, f"shipped model {path.stem} is missing (see models/README.md to train it)")
        kwargs.setdefault("name", path.stem)
    predictor = VOPredictor.from_file(path, **kwargs)
    predictor.mirror_average = models.mirror_average(mirror_average, predictor.meta, net_pose)
    return predictor


def model_odometry(path: str | Path, flow: str = "dis", shipped: bool = False, progress: bool = False,
                   pose: str | None = None, flow_options: dict | None = None, scale: str | None = None,
                   estimator=None, std_from_geometry: bool = False, mirror_average: str = models.MIRROR_AVERAGE_DEFAULT,
                   **kwargs):
    """The VO model file at ``path`` as a SLAM odometry (:meth:`vo.infer.VOPredictor.as_odometry`) on flow
    estimator ``flow`` set up as the file records (:func:`vo.modelfiles.models.flow_for_model`), each of
    ``flow_options`` (e.g. ``{"patch_stride": 4}``) taking precedence, or on ``estimator`` when given (one
    estimator shared by several models), in pose mode ``pose`` (:data:`vo.modelfiles.models.POSES`; None: the
    mode the file records) with distance source ``scale`` (:data:`vo.modelfiles.models.SCALES`; None: the
    file's); ``std_from_geometry``: each std widened by the geometry's disagreement (``vo --std-from-geometry``:
    the epipolar fit with the road's distance; InputError with an epipolar pose of another distance source);
    ``mirror_average``: :data:`vo.modelfiles.models.MIRROR_AVERAGE`'s choice (``vo --mirror-average``);
    ``kwargs`` go to :func:`load_predictor`."""
    epipolar = models.epipolar_config(path, pose, scale)
    geometry = models.geometry_config(path, epipolar) if std_from_geometry else None
    if estimator is None:
        estimator = models.flow_for_model(flow, path, **(flow_options or {}))
    return load_predictor(Path(path), shipped, mirror_average, epipolar is None, **kwargs).as_odometry(
        estimator, progress=progress, epipolar=epipolar, geometry=geometry)


def resolve_predictor(spec: str | None, seq=None, which: str = "cons", flow=None, **kwargs):
    """A predictor from ``spec``: a model file path, ``kitti``/``euroc`` (shipped ``cons``),
    ``kitti:loops``-style shipped names, or None (the shipped model for ``seq``'s camera kind). Shipped
    models follow ``flow`` (the estimator's name or object, see :func:`vo.modelfiles.models.shipped_path`); a file is taken as is."""
    return load_predictor(*models.locate(spec, seq, which, flow), **kwargs)


class PaperNetwork:
    """The paper's network as an odometry plug-in (``--odometry network``, entry point ``network``): the shipped
    NN_cons of the sequence's camera kind on DIS flow (set up as that model was trained), read with the network's
    own pose: no essential matrix, no road scale. What the paper evaluates, measured beside ``deepslam vo``'s
    default (which reads the same network's flow through the epipolar pose and the road scale on streets)."""

    name = "paper-network"
    """The shipped NN_cons, its own pose, on DIS flow."""

    def __init__(self):
        self._by_kind: dict = {}

    def predict(self, seq, pairs):
        """(mean6, std6) per pair (i, j) of ``seq``: the paper's vector of ``cam_j_from_cam_i`` and its std."""
        kind = kind_for_sequence(seq)
        if kind not in self._by_kind:
            path, shipped = models.locate(None, seq, "cons", "dis")
            self._by_kind[kind] = model_odometry(path, "dis", shipped, pose="net")
        return self._by_kind[kind].predict(seq, pairs)


def make_network() -> PaperNetwork:
    """The entry point's factory (``--odometry network`` or ``--odometry deepslam.vo.odometry:make_network``)."""
    return PaperNetwork()
