"""``deepslam render``: render a simulated sequence with perfect ground truth (RGB, depth, flow, poses, masks)."""
from __future__ import annotations

import argparse
import json
import time

from deepslam.core.errors import InputError

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "render"
HELP = "render a simulated sequence (street/room, car/drone) with exact depth, flow, poses and masks"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scene", default="street",
                   help="street (KITTI-like town), room (EuRoC-like hall), or a scene file (.yaml/.json) adding your "
                        "own OBJ/GLB/PLY meshes to one of them (README: Your own meshes); default street")
    p.add_argument("--trajectory", default="auto",
                   help="car, drone, handheld (room only: a camera walked round the table) or auto (street: car, "
                        "room: drone); default auto")
    p.add_argument("--frames", type=int, default=300, help="number of frames (default 300)")
    p.add_argument("--out", required=True, help="output folder (must not exist or be empty, unless --resume)")
    p.add_argument("--format", default="ours",
                   help="ours, kitti, euroc or tum (TUM RGB-D: rgb.txt, depth.txt, 16-bit depth PNGs at 5000 per "
                        "metre, groundtruth.txt, intrinsics.txt); default ours")
    p.add_argument("--flow-format", default="npy", metavar="FMT[,FMT]",
                   help="flow files written beside each flow/ and flow_backward/ .npy, comma-separated: npy (always), "
                        "flo (Middlebury, float32), png (KITTI 2015 flow PNG, 1/64 px); default npy")
    p.add_argument("--backend", default="mujoco", help="mujoco or pyrender (default mujoco)")
    p.add_argument("--width", type=int, default=None, help="image width in pixels (default: the scene camera's)")
    p.add_argument("--height", type=int, default=None, help="image height in pixels (default: from the width and the scene camera's aspect)")
    p.add_argument("--stereo-baseline", type=float, default=None, metavar="B",
                   help="right camera at +B metres along x; 0 = mono (default: the scene's, street 0.54, room 0.11)")
    p.add_argument("--moving-objects", type=int, default=0, metavar="K", help="moving cars (street) or flying boxes (room)")
    p.add_argument("--deform", type=float, default=0.0, metavar="A", help="amplitude of the waving flags in metres (0 = static)")
    p.add_argument("--seed", type=int, default=None, help="seed of the scene and trajectory (default: the scene "
                                                              "file's, else 0)")
    p.add_argument("--rate", type=float, default=None, help="frame rate in Hz (default: car 10, drone 20, handheld 30)")
    p.add_argument("--camera-ahead", type=float, default=0.0, metavar="M",
                   help="car: the camera this far ahead of the rear axle, metres, so that it slides sideways in turns "
                        "as a real car's does (KITTI's ground truth fits 0.84); default 0: on the axle's path")
    p.add_argument("--body-motion", type=float, default=0.0, metavar="S",
                   help="car: the body's pitch and roll on its suspension, S times KITTI's (1: 0.17 and 0.15 degrees "
                        "RMS from frame to frame at 10 Hz); default 0: the camera keeps the road's attitude")
    p.add_argument("--texture-density", type=float, default=None, metavar="PX_PER_M",
                   help="texels per metre of the procedural textures (default: street 20, room 100)")
    p.add_argument("--kitti-sequence", default=None, metavar="NN",
                   help="--format kitti: the sequence number, two digits, the folder sequences/NN (default 00)")
    p.add_argument("--no-flow", action="store_true", help="skip the ground-truth flow")
    p.add_argument("--resume", action="store_true", help="finish an interrupted render in --out (same settings)")
    p.add_argument("--focal-px", type=float, default=None, metavar="F",
                   help="focal length fx = fy in pixels (e.g. 537 for a Kinect at 640x480); default: the scene "
                        "camera's field of view")
    p.add_argument("--principal-point", default=None, metavar="CX,CY",
                   help="the images' principal point, pixels (default: the image centre; its offset from the centre "
                        "must be a multiple of 0.5 px), as a real camera's: KITTI 04-12's, at 414x125, is about 203,61.5. "
                        "Rendered centred on a larger canvas and cut, so every output is exact")
    p.add_argument("--depth-noise", choices=("none", "kinect"), default="none",
                   help="kinect: write depth/ as a structured-light sensor reports it (range 0.5-4.5 m, noise "
                        "growing with depth^2, disparity quantisation, missing readings at edges and grazing "
                        "angles); the exact depth goes to depth_exact/ and the other ground truth stays exact")
    p.add_argument("--street-style", choices=("kitti", "town"), default=None,
                   help="street: kitti (narrow residential streets and a long avenue, grainy asphalt, cars parked "
                        "along both kerbs, stop-and-go driving from 0 to about 30 m/s, the camera pitched 1 degree "
                        "down, cars driving ahead in view) or town (the two-block town of uniform roads; the layout "
                        "and road options below are its own); default kitti, or town with one of those options")
    p.add_argument("--varied-layout", action="store_true",
                   help="street: a narrow, crowded variant of the town from the seed (closer facades, more parked "
                        "cars and trees by the kerb), like KITTI's residential streets")
    p.add_argument("--route", choices=("default", "laps"), default="default",
                   help="street (KITTI look): the ego car's route; laps: a lap of the block, then every road of the "
                        "town once in each direction (loop closures the same way and the opposite way; about "
                        "1.75 km, about 1,600 frames at 10 Hz for one round)")
    p.add_argument("--narrow-layout", action="store_true",
                   help="street: a narrow residential street from the seed (8-10 m kerb to kerb, cars parked along "
                        "both kerbs, facades close behind them)")
    p.add_argument("--grainy-road", action="store_true",
                   help="street: asphalt with visible grain (contrast drawn per road stretch) instead of the "
                        "near-uniform surface, so that flow estimators read the road's motion as on real roads")
    p.add_argument("--exposure-ms", type=float, default=0.0, metavar="MS",
                   help="motion blur: the image averaged over this exposure, centred on the frame time (whose pose, "
                        "depth, flow and masks stay exact: they are mid-exposure's); 0 = sharp")
    p.add_argument("--blur-samples", type=int, default=8, help="renders averaged per blurred image (default 8)")
    p.add_argument("--rolling-shutter-ms", type=float, default=0.0, metavar="MS",
                   help="rolling shutter: rows read out top to bottom over this time, the middle row at the frame "
                        "time; per-row poses in row_poses/, flow and occlusion exact for the rows as captured")
    p.add_argument("--rolling-shutter-bands", type=int, default=32, metavar="K",
                   help="rows rendered in K bands, each at its middle row's time (default 32; the image height: "
                        "every row its own time)")
    p.add_argument("--random-lighting", action="store_true",
                   help="draw the lighting from the seed: sun direction, shadow depth, brightness, colour temperature")
    p.add_argument("--sensor-noise", type=float, default=0.0, metavar="STD", help="Gaussian image noise, grey levels")
    p.add_argument("--exposure-jitter", type=float, default=0.0, metavar="J",
                   help="per-frame brightness gain, log-uniform in [1/(1+J), 1+J] (auto-exposure)")
    p.add_argument("--white-balance-jitter", type=float, default=0.0, metavar="W",
                   help="per-frame colour channel gains, uniform in [1-W, 1+W]")
    p.add_argument("--distortion", default=None, metavar="K1,K2,P1,P2",
                   help="lens distortion of the images (OpenCV radial-tangential), --format euroc only: written to "
                        "sensor.yaml; the reader undistorts back to the render's pinhole camera, where depth, flow and "
                        "masks are")
    p.add_argument("--preview", default=None, metavar="PNG",
                   help="also write a contact sheet: up to 6 frames as rows of RGB | depth | flow | mask "
                        "(outside --out)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true",
                   help="no progress bar; print one JSON object at the end: path, frames, seconds, dynamic_fraction "
                        "(mean and max share of the image on dynamic surfaces, from dynamic_fraction.txt), preview")


def NEEDS(args: argparse.Namespace) -> tuple[str, ...]:
    """Optional modules this run needs (checked before any work by the command line): the [sim] extra."""
    return ("mujoco",) + (("pyrender",) if args.backend == "pyrender" else ())


def _numbers(text: str | None, flag: str, names: str) -> tuple[float, ...] | None:
    """``flag``'s comma-separated value as one float per name of ``names`` (e.g. ``CX,CY``); None when not given."""
    if text is None:
        return None
    count = names.count(",") + 1
    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise InputError(None, f"{flag} must be {names}, got {text!r}") from None
    if len(values) != count:
        raise InputError(None, f"{flag} must be {({2: 'two', 4: 'four'}).get(count, count)} numbers {names}, got {text!r}")
    return values


def _kitti_sequence(args: argparse.Namespace) -> str:
    if args.kitti_sequence is None:
        return "00"
    if args.format != "kitti":
        raise InputError(None, f"--kitti-sequence names a folder of --format kitti, not of --format {args.format}")
    if not (args.kitti_sequence.isdigit() and len(args.kitti_sequence) == 2):
        raise InputError(None, f"--kitti-sequence must be two digits NN, got {args.kitti_sequence!r}")
    return args.kitti_sequence




def run(args: argparse.Namespace) -> int:
    from deepslam.core.preview import check_sheet_path, write_contact_sheet
    from deepslam.scenes import SceneConfig
    from deepslam.sim.config import RenderConfig, SimConfig, TrajectoryConfig
    from deepslam.sim.writers import read_dynamic_fractions, render_sequence

    scene_name, scene_file, seed = args.scene, None, args.seed
    from deepslam.scenes.custom import is_scene_file, load_scene_file

    if is_scene_file(args.scene):
        spec = load_scene_file(args.scene)
        scene_name, scene_file = spec.base, str(spec.path)
        seed = seed if seed is not None else spec.seed
    cfg = SimConfig(
        SceneConfig(name=scene_name, seed=0 if seed is None else seed, moving_objects=args.moving_objects, scene_file=scene_file,
                    deform_amplitude_m=args.deform, texture_px_per_m=args.texture_density,
                    varied_layout=args.varied_layout, narrow_layout=args.narrow_layout,
                    random_lighting=args.random_lighting, grainy_road=args.grainy_road,
                    street_style=args.street_style, route=args.route),
        TrajectoryConfig(kind=args.trajectory, frames=args.frames, rate_hz=args.rate, camera_ahead_m=args.camera_ahead,
                         body_motion=args.body_motion),
        RenderConfig(backend=args.backend, width=args.width, height=args.height,
                     stereo_baseline_m=args.stereo_baseline, focal_px=args.focal_px,
                     principal_point_px=_numbers(args.principal_point, "--principal-point", "CX,CY"),
                     flow=not args.no_flow,
                     depth_noise=None if args.depth_noise == "none" else args.depth_noise,
                     exposure_ms=args.exposure_ms, blur_samples=args.blur_samples, sensor_noise=args.sensor_noise,
                     exposure_jitter=args.exposure_jitter, white_balance_jitter=args.white_balance_jitter,
                     distortion=_numbers(args.distortion, "--distortion", "K1,K2,P1,P2"),
                     rolling_shutter_ms=args.rolling_shutter_ms,
                     rolling_shutter_bands=args.rolling_shutter_bands, flow_formats=args.flow_format),
    ).validate()
    kitti_sequence = _kitti_sequence(args)
    if args.preview:  # checked before rendering: never inside the sequence nor onto the scene file
        check_sheet_path(args.preview, [("--out", args.out), ("--scene", scene_file)])
    t0 = time.perf_counter()
    path = render_sequence(cfg, args.out, fmt=args.format, resume=args.resume,
                           progress=not (args.quiet or args.json), sequence=kitti_sequence)
    seconds = time.perf_counter() - t0
    sheet = write_contact_sheet(path, args.preview) if args.preview else None
    if args.json:
        dyn = read_dynamic_fractions(path)
        print(json.dumps({"path": str(path), "format": args.format, "frames": len(dyn) or args.frames,
                          "seconds": round(seconds, 2),
                          "dynamic_fraction": {"mean": sum(dyn) / len(dyn), "max": max(dyn)} if dyn else None,
                          "preview": None if sheet is None else str(sheet)}))
        return 0
    print(path)
    if sheet is not None:
        print(sheet)
    return 0
