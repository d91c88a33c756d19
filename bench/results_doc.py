"""docs/results.md from the results on disk: every table ``make results`` and ``make bench`` wrote under out/,
each under its heading with the command that remakes it and the stamp of the run that measured it (date,
commit, machine: ``stamp.json`` beside the table, :mod:`bench.stamp`). Nothing in docs/results.md is written
by hand; a table whose run left no stamp says so. A table whose run is not on disk (a fresh clone, or only some
of ``make results`` re-run) is kept as the previous docs/results.md had it, under its own stamp. The figures a
table shows (``![...](name.png)`` beside its results.md) are copied to docs/img/results/ and linked from there;
a figure that is not on disk is left out.

    python -m bench.results_doc [--out docs/results.md]      # the last step of `make results`
"""
from __future__ import annotations

import argparse
import json
import re
import shutil
from pathlib import Path

from bench.stamp import stamp
from deepslam.core import atomic
from deepslam.core.paths import out_dir

REPO = Path(__file__).resolve().parents[1]

SECTIONS = (
    # (folder under out/results, heading, command that remakes it, what it shows)
    ("claim", "The paper's claim in its tables' layout: single frames against supervised, and the defaults",
     "python -m bench.results_claim  # after bench.results_lever and bench.results_repro_rgbd",
     "NN_cons trained by the paper's recipe from single frames and supervised on the same renders, read with its "
     "own pose on an unseen town, KITTI 06 and 07, unseen rooms and TUM teddy, mean ± std over seeds, beside "
     "`deepslam vo`'s default and pnp; the ratios the recipe is judged on."),
    ("agreement", "Does the simulator predict reality? Sim against real, variant by variant", "python -m bench.results_agreement",
     "Path-length ratio and drift of the odometry variants on unseen simulated streets and on real KITTI at frame "
     "strides 1-3, and the rank agreement of the two."),
    ("slam", "VO alone against SLAM", "python -m bench.results_slam",
     "ATE of the odometry alone and of the SLAM pose graph on simulated streets and rooms."),
    ("keyframes", "Relocalization on every k-th frame", "python -m bench.results_keyframes",
     "deepslam slam's defaults with keyframe strides 1-3 on loop routes and a room: loop recall, SLAM ATE and what "
     "relocalization costs; the rule that decides the default stride."),
    ("width", "The default odometry at every width", "python -m bench.results_width",
     "deepslam vo's default as recorded and read upsampled to 640 px on unseen streets rendered at 320-1241 px, "
     "rooms, the README's 320 px streets beside pnp, and KITTI; the rule that decides the default read width."),
    ("vo", "Training on single frames against supervised training", "python -m bench.results_vo",
     "The paper's synthetic training (single frames, no poses) against training on ground-truth poses, over seeds, "
     "at a small budget (49,152 samples a model: under a minute of training); the recipe at scale is the claim "
     "table's (first section)."),
    ("exact_model", "Which model reads the simulator's exact flow on streets", "python -m bench.results_exact_model",
     "The shipped kitti_cons against the paper recipe's synthetic models on unseen streets at three widths and "
     "strides 1-3, exact flow, each model's own pose; the rule that decides which `deepslam vo --flow gt` runs."),
    ("repro", "The paper's recipe at scale: single frames against supervised, the network's own pose",
     "LEVER=0 MIRROR_FRAMES=0 bash scripts/train_paper_recipe.sh bench/paper_recipe  # hours on 2 cores, minutes on a GPU; then "
     "python -m bench.results_repro",
     "NN_cons trained by the paper's recipe for up to 2 M samples (three seeds of the cpu preset, one of the paper's "
     "96 x 320 network; the synthetic model also on DIS flow of views rendered from the single frames, and that with "
     "the motions' turn radius freed or mirrored), synthetic "
     "from single frames and supervised on the same renders, scored with their own pose on a held-out street (exact "
     "and DIS flow) and on KITTI 06 and 07, beside the geometry default and pnp; where the own pose's drift comes "
     "from (rotation or distance); calibration; learning curves."),
    ("repro_rgbd", "The paper's recipe on RGB-D: rendered rooms and TUM teddy, the network's own pose",
     "SCENE=room bash scripts/train_paper_recipe.sh bench/paper_recipe  # then python -m bench.results_repro_rgbd",
     "NN_cons trained by the paper's recipe on single frames of rendered Kinect-like rooms and supervised on the same "
     "renders' pairs, scored with their own pose on an unseen room flown by a drone and walked hand-held (exact and "
     "DIS flow) and on TUM fr3/teddy, beside the RGB-D default and pnp; whether each rendered room ranks the rows as "
     "teddy does."),
    ("lever", "The camera's lever arm: the recipe trained on towns whose camera sits where KITTI's does",
     "bash scripts/train_paper_recipe.sh bench/paper_recipe  # LEVER=0.84, the default; the models named without "
     "_mirrorframes with MIRROR_FRAMES=0; then python -m bench.results_lever",
     "KITTI's camera is 0.84 m ahead of the rear axle and slides sideways into every turn; the recipe's models "
     "trained on towns whose camera rides on the axle against the same recipe on towns rendered with the lever, "
     "scored with their own pose on town 7 without and with the lever and on the KITTI slices: the turns' mean yaw "
     "error, the drift left under the true rotation, and each model's distance on the KITTI slices at strides "
     "1-3 by the length of the motion."),
    ("layout", "Where the network reads the distance from: the towns' layout",
     "python -m bench.results_layout",
     "The recipe's towns keep their car to the right; on the straight pairs of the held-out town and the KITTI "
     "slices (DIS flow), each model's forward gain on the flow as seen and mirrored left-right, and where in the "
     "image its forward reading comes from (integrated gradients): a network that learned where the towns' open "
     "road lies over-reads a street laid out otherwise."),
    ("extra", "Rendered frames as extra training data", "python -m bench.results_extra",
     "One network and budget trained the paper's way on real single frames (KITTI 06), real plus rendered, and "
     "rendered alone; scored on KITTI 07, which none of them saw."),
    ("speed", "Distance read at several speeds", "python -m bench.results_speed",
     "Path-length ratio of the shipped odometry on simulated streets and real frames at several frame strides."),
    ("road", "Road geometry", "python -m bench.results_road",
     "Camera height read from the road against the truth."),
    ("real", "Real data slices", "python -m bench.results_real",
     "The shipped models on the real KITTI, EuRoC and TUM slices in ../shared/data."),
    ("turn", "Turns", "python -m bench.results_turn", "Rotation read in turns on KITTI 07."),
    ("adapt", "RGB-D: the sim-only default, the untrained dense fit, pnp and deepslam adapt", "python -m bench.results_adapt",
     "VO ATE on teddy and two rendered Kinect-like rooms; on teddy also the model deepslam adapt made from teddy's "
     "own frames (it has seen them)."),
    ("tum", "RGB-D odometry (TUM fr3/teddy)", "python -m bench.results_tum",
     "The RGB-D default, the untrained dense fit and the classical pnp plug-in on teddy."),
    ("stress", "Stress study: moving and deforming objects", "python -m bench.results_stress",
     "deepslam stress with its defaults on the default street: flow, VO and SLAM errors against the fraction of "
     "moving pixels, `deepslam vo`'s default beside the paper's network (its own pose) and pnp."),
    ("flow", "Learned optical flow against DIS (shipped model)", "python -m bench.results_flow",
     "End-point error and Fl-all on held-out renders; forward-backward consistency on real KITTI."),
    ("flow_gpu", "The flow network trained on a GPU against DIS and the shipped network",
     "bash scripts/device_flow_train.sh  # on the GPU machine; then python -m bench.results_flow --model "
     "out/device/stage2/flow.safetensors --held out/flow_held_gpu/street_201 out/flow_held_gpu/street_202 "
     "out/flow_held_gpu/room_203 --pairs 15 --out out/results/flow_gpu",
     "Scored on the CPU on the same held-out renders and real pairs as the shipped network's row "
     "(``flow_shipped``)."),
    ("flow_shipped", "The shipped flow network on the GPU network's held-out renders",
     "python -m bench.results_flow --held out/flow_held_gpu/street_201 out/flow_held_gpu/street_202 "
     "out/flow_held_gpu/room_203 --pairs 15 --out out/results/flow_shipped",
     "The baseline of the table above, same pairs."),
)


def _stamp_line(folder: Path) -> str:
    f = folder / "stamp.json"
    if f.is_file():
        s = json.loads(f.read_text())
        extra = "".join(f"; {k}: {v}" for k, v in s.items() if k not in ("date", "commit", "machine"))
        return f"*Measured {s['date']}, commit `{s['commit']}`, on {s['machine']}{extra}.*"
    return "*This run left no stamp (date, commit and machine unknown).*"


DEVICE_HEADING = "Training on a GPU machine (bench/bench_device.py)"


def _device_section(out: Path) -> list[str]:
    """The GPU machine's bench rows (bench/bench_device.py run by scripts/device_flow_train.sh), if there."""
    rows_file = out / "device" / "stage1" / "bench_device.json"
    if not rows_file.is_file():
        return []
    rows = json.loads(rows_file.read_text())
    lines = [f"## {DEVICE_HEADING}", "",
             "Run by `scripts/device_flow_train.sh` on one NVIDIA H200 (16 CPU cores there); the CPU rows are that "
             "machine's CPU, in the same run.", ""]
    s = out / "device" / "stamp.json"
    lines += [_stamp_line(s.parent) if s.is_file() else "*Stamp: see docs/experiments/2026-12-04_gpu_flow.md.*", ""]
    lines += ["| measurement | value | unit | against | ratio |", "|---|---|---|---|---|"]
    for r in rows:
        ratio = f"{r['ratio']:.2f}" if r.get("ratio") is not None else ""
        lines.append(f"| {r['name']} | {r['value'] if r['value'] is not None else ''} | {r['unit']} | "
                     f"{r.get('baseline') or ''} | {ratio} |")
    return lines + [""]


_FIGURE = re.compile(r"!\[([^\]]*)\]\(([^)\s]+\.png)\)")
FIGURES = "img/results"
"""Where the tables' figures are copied, relative to docs/results.md."""


def _link_figures(text: str, folder: Path, name: str, figures: dict[str, Path]) -> str:
    """``text`` with each figure link relative to ``folder`` pointing at its copy under :data:`FIGURES`
    (``{name}_{file}``, added to ``figures``: link -> source); links to missing files are dropped."""

    def relink(m: re.Match) -> str:
        src = folder / m.group(2)
        if not src.is_file():
            return ""
        link = f"{FIGURES}/{name}_{src.name}"
        figures[link] = src
        return f"![{m.group(1)}]({link})"

    return _FIGURE.sub(relink, text)


BENCH_HEADING = "Speed and memory against same-run baselines (`make bench-speed`)"


def previous_sections(text: str) -> dict[str, list[str]]:
    """The sections of an earlier docs/results.md: heading -> its lines (heading included, trailing blank
    lines dropped). A section runs to the next of this module's headings (a table's own ``## `` lines, such as
    its commands, stay in it)."""
    headings = {BENCH_HEADING, DEVICE_HEADING} | {h for _, h, _, _ in SECTIONS}
    sections: dict[str, list[str]] = {}
    current: list[str] | None = None
    for line in text.splitlines():
        if line.startswith("## ") and line[3:].strip() in headings:
            current = sections.setdefault(line[3:].strip(), [])
        if current is not None:
            current.append(line)
    for body in sections.values():
        while body and not body[-1].strip():
            body.pop()
    return sections


def build(out: Path, figures: dict[str, Path] | None = None, previous: str = "") -> str:
    """The whole document from the results under ``out``; the figures it links are added to ``figures``
    (link relative to the document -> file under ``out``). ``previous``: the earlier document, whose section
    is kept for each table not on disk under ``out`` (its figures are already beside it)."""
    figures = {} if figures is None else figures
    kept = previous_sections(previous)
    now = stamp()
    lines = ["# Results", "",
             f"Generated by `make results` (`python -m bench.results_doc`) on {now['date']} at commit "
             f"`{now['commit']}`. Each table carries the stamp of the run that measured it; a table whose run "
             "is not on this checkout is kept from the previous document, under its own stamp. Decision "
             "records: [experiments/](experiments/).",
             ""]
    bench_json = out / "bench.json"
    if bench_json.is_file():
        doc = json.loads(bench_json.read_text())
        meta = doc.get("meta", {})
        lines += [f"## {BENCH_HEADING}", "",
                  f"*Measured {meta.get('date', meta.get('time', '?'))}, commit `{meta.get('commit', '?')}`, on "
                  f"{meta.get('machine', '?')}.*", "", (out / "bench.md").read_text().strip()
                  if (out / "bench.md").is_file() else "", ""]
    elif BENCH_HEADING in kept:
        lines += kept[BENCH_HEADING] + [""]
    for name, heading, command, what in SECTIONS:
        folder = out / "results" / name
        table = folder / "results.md"
        if not table.is_file():
            if heading in kept:
                lines += kept[heading] + [""]
            continue
        lines += [f"## {heading}", "", what, "", f"Remake: `{command}`", "", _stamp_line(folder), "",
                  _link_figures(table.read_text().strip(), folder, name, figures), ""]
    device = _device_section(out)
    if device:
        lines += device
    elif DEVICE_HEADING in kept:
        lines += kept[DEVICE_HEADING] + [""]
    return "\n".join(lines).rstrip() + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.results_doc", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "results.md")
    args = ap.parse_args(argv)
    figures: dict[str, Path] = {}
    text = build(out_dir(), figures, args.out.read_text() if args.out.is_file() else "")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    for link, src in figures.items():
        dst = args.out.parent / link
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, dst)
    atomic.write_text(args.out, text)
    print(f"wrote {args.out} ({text.count(chr(10))} lines)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
