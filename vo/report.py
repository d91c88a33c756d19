"""What ``deepslam vo`` writes and prints of a :func:`vo.pipeline.run_vo` result: the motions table
(``<stem>.motions.csv``), the metrics against the ground truth (``<stem>.metrics.json``), the plot's title and
the summary line.
"""
from __future__ import annotations

from deepslam.core import metrics

MOTIONS_HEADER = ("i,j,t_i_s,t_j_s,ex_rad,ey_rad,ez_rad,tx_m,ty_m,tz_m,"
                  "std_ex_rad,std_ey_rad,std_ez_rad,std_tx_m,std_ty_m,std_tz_m")
"""Columns of the motions table: frame indices, their timestamps (s), the paper's 6DoF of cam_j_from_cam_i
(radians, metres) and its predicted standard deviations."""


def motions_csv(seq, res) -> str:
    """The motions table of ``res`` (:class:`vo.pipeline.VOResult`) on ``seq``: one row a pair, every float in
    full precision (``repr``)."""
    lines = [MOTIONS_HEADER]
    for (i, j), m, s in zip(res.pairs, res.mean6, res.std6):
        lines.append(",".join([str(int(i)), str(int(j)), repr(float(seq.timestamps_s[i])),
                               repr(float(seq.timestamps_s[j])), *(repr(float(x)) for x in m),
                               *(repr(float(x)) for x in s)]))
    return "\n".join(lines) + "\n"


def score(seq, res) -> tuple[dict, object, object]:
    """(report, gt, est) of ``res`` on a sequence with ground truth: the metrics (:func:`core.metrics.evaluate`,
    se3-aligned, with ``ate_unaligned_m``, ``frames_scored`` and ``frames``) over the frames the ground truth
    covers, and the two :class:`core.trajectory.Trajectory` compared there."""
    gt, est = metrics.on_covered_frames(seq, res.world_from_cam, res.frames)
    ev = metrics.evaluate(gt, est, align="se3")
    report = {k: v for k, v in ev.items() if not k.startswith("_")}
    report["ate_unaligned_m"] = metrics.evaluate(gt, est, align="none")["ate_m"]
    report["frames_scored"], report["frames"] = len(gt), int(len(res.frames))
    return report, gt, est


def plot_title(seq, name: str, config: dict) -> str:
    """The plot's title: the sequence, the odometry and how it ran (flow, epipolar pose, road scale)."""
    how = [config["flow"]] if "flow" in config else []
    how += ["pose epipolar"] if config.get("pose") == "epipolar" else []
    how += ["scale road"] if (config.get("epipolar") or {}).get("road_height_m") is not None else []
    return f"{seq.name}: {name}" + (f" ({', '.join(how)})" if how else "")


def summary_line(report: dict, stride: int) -> str:
    """One line of the metrics a user reads first: ATE (aligned and not), RPE per ``stride`` frames, KITTI's
    errors where the path is long enough, path ratio and end-point drift."""
    line = (f"ATE {report['ate_m']:.3f} m (se3-aligned; {report['ate_unaligned_m']:.3f} m unaligned), "
            f"RPE {report['rpe_t_m']:.3f} m / {report['rpe_r_deg']:.3f} deg per {stride} frame(s)")
    if "kitti_t_err_pct" in report:
        line += (f", KITTI t_err {report['kitti_t_err_pct']:.2f} %, "
                 f"r_err {report['kitti_r_err_deg_per_100m']:.2f} deg/100 m")
    line += (f"; path x{report['path_length_ratio']:.3f}, end-point drift {report['endpoint_drift_pct']:.1f} % "
             "of the path")
    if report["frames_scored"] < report["frames"]:
        line += f" (scored on the {report['frames_scored']} of {report['frames']} frames the ground truth covers)"
    return line
