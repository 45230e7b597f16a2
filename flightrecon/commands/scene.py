"""`flightrecon scene make|info|tour|scanify`: write a procedural scene, describe a scene file, render
views, write a scan-like mesh of a procedural scene."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from flightrecon.errors import SceneError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("scene", help="procedural scenes and scene files (make, info, tour, scanify)")
    ssub = p.add_subparsers(dest="scene_cmd", metavar="ACTION")

    mk = ssub.add_parser("make", help="write a procedural scene as Replica's DIR/mesh.ply")
    mk.add_argument("name", help="office0..office4, room0..room2")
    mk.add_argument("--out", required=True, help="output folder")
    mk.add_argument("--seed", type=int, default=0)
    mk.set_defaults(func=_make)

    info = ssub.add_parser("info", help="counts, bounds, up axis, colors/texture, free volume of a scene")
    _scene_args(info)
    info.add_argument("--json", action="store_true", help="print JSON instead of text")
    info.add_argument("--max-height", type=float, default=None,
                      help="planner.max_height: workspace top above the floor where there is no ceiling (m)")
    info.set_defaults(func=_info)

    tour = ssub.add_parser("tour", help="render RGB-D views from the scene's center to PNG files")
    _scene_args(tour)
    tour.add_argument("--out", required=True, help="output folder")
    tour.add_argument("--views", type=int, default=8, help="number of headings around the center")
    tour.add_argument("--width", type=int, default=640)
    tour.add_argument("--height", type=int, default=480)
    tour.add_argument("--hfov", type=float, default=90.0, help="horizontal field of view (deg)")
    tour.add_argument("--pitch", type=float, default=10.0, help="camera pitch, positive looks down (deg)")
    tour.set_defaults(func=_tour)

    scan = ssub.add_parser("scanify", help="a scan-like mesh of a procedural scene (fused noisy hand-held depth, "
                                           "holes, any frame and units) with its truth in <out>.truth.json")
    scan.add_argument("name", help="office0..office4, room0..room2")
    scan.add_argument("--out", required=True, help="mesh file: .ply (vertex colours) or .obj (texture atlas, "
                                                   "with .mtl and .png beside it)")
    scan.add_argument("--seed", type=int, default=0, help="seed of the scene and of the scan")
    scan.add_argument("--convention", help="frame of the file: camera (the first camera's, OpenCV axes), y-up, "
                                           "-y-up or z-up (default); write --convention=-y-up")
    scan.add_argument("--units", help="m (default), cm or mm")
    scan.add_argument("--ceiling", help="full (default: the operator looks up too), partial (hardly) or none "
                                        "(cropped off)")
    scan.add_argument("--wall-top", type=float, help="crop above this height over the floor (m): walls end low")
    scan.add_argument("--holes", type=int, help="extra holes cut in the surface (default 0)")
    scan.add_argument("--furniture", action="store_true", default=None,
                      help="a box 0.9-1.3 m tall where the default take-off point is")
    scan.add_argument("--heading-deg", type=float, help="turn about up before storing (axis conventions)")
    scan.add_argument("--offset", type=float, nargs=3, metavar=("X", "Y", "Z"),
                      help="shift (m) before storing (axis conventions)")
    scan.add_argument("--frames", type=int, help="hand-held poses (default 90)")
    scan.add_argument("--voxel", type=float, help="TSDF voxel (m, default 0.03)")
    scan.add_argument("--max-faces", type=int, help="decimate to this many triangles (default 150000; 0: keep all)")
    scan.set_defaults(func=_scanify)
    p.set_defaults(func=lambda a: p.print_help())


def _scene_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="a procedural scene name or a mesh file (PLY, OBJ, GLB) / Replica folder")
    p.add_argument("--seed", type=int, default=0, help="seed of a procedural scene")
    p.add_argument("--unit-scale", type=float, default=1.0, help="file units to meters")
    p.add_argument("--up-axis", choices=("z", "y", "auto"), default="auto",
                   help="up axis of the file; auto: estimated from its floor and walls (default)")
    p.add_argument("--up-vector", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="the file's up direction, overriding --up-axis (scene.up_vector)")
    p.add_argument("--rotation-deg", type=float, nargs=3, default=None, metavar=("RX", "RY", "RZ"),
                   help="extra rotation about world x, y, z after the up axis (scene.rotation_deg)")
    p.add_argument("--cache-dir", default="", help="cache folder (default ~/.cache/flightrecon)")


def _load(args):
    from flightrecon.scene.loaders import load_scene
    from flightrecon.scene.procedural import SCENE_NAMES
    from flightrecon.scene.source import procedural_scene

    if args.scene in SCENE_NAMES and not Path(args.scene).exists():
        return procedural_scene(args.scene, args.seed, args.cache_dir)
    return load_scene(args.scene, unit_scale=args.unit_scale, up_axis=args.up_axis, up_vector=args.up_vector,
                      rotation_deg=args.rotation_deg)


def _make(args) -> int:
    from flightrecon.scene.procedural import make_scene
    from flightrecon.scene.source import write_scene_dir

    scene = make_scene(args.name, args.seed)
    path = write_scene_dir(scene, args.out)
    print(f"wrote {path} ({len(scene.vertices)} vertices, {len(scene.faces) // 2} quads)")
    return 0


def scan_options(args):
    """The ScanOptions of `scene scanify`'s arguments: those given, ScanOptions' defaults for the rest."""
    from flightrecon.scene.scanify import ScanOptions

    given = {key: getattr(args, key) for key in ("convention", "units", "ceiling", "wall_top", "holes", "furniture",
                                                 "heading_deg", "frames", "voxel") if getattr(args, key) is not None}
    if args.offset is not None:
        given["offset"] = tuple(args.offset)
    if args.max_faces is not None:
        given["max_faces"] = args.max_faces or None
    return ScanOptions(**given)


def _scanify(args) -> int:
    from flightrecon.scene.scanify import scan_procedural, write_scan

    options = scan_options(args)  # bad options fail here, before the scan
    scan = scan_procedural(args.name, args.seed, options)
    written = write_scan(scan, args.out)
    t = scan.truth
    up = ", ".join(f"{x:.3f}" for x in t["up"])
    print(f"wrote {written[0]} ({len(scan.vertices)} vertices, {len(scan.faces)} triangles, "
          f"{t['frames']} frames fused)")
    print(f"truth in {written[-1]}: up ({up}), floor {t['floor']:.3f} {t['units']} along it; "
          f"kinds {', '.join(json.loads(written[-1].read_text())['kinds'])}")
    return 0


def _info(args) -> int:
    from flightrecon.planning.poses import start_position, workspace_of
    from flightrecon.scenario import load_config
    from flightrecon.scene.free_space import HOLE_RADIUS
    from flightrecon.scene.stats import summary

    scene = _load(args)
    cfg = load_config(None, [] if args.max_height is None else [f"planner.max_height={args.max_height}"])
    s = summary(scene, start_position(scene, cfg.sim.takeoff_height))
    work = workspace_of(scene, cfg.planner.max_height)
    s["workspace_min"], s["workspace_max"] = ([round(float(x), 3) for x in b] for b in work)
    s["required_clearance"] = cfg.required_clearance
    s["max_height"] = cfg.planner.max_height
    if args.json:
        print(json.dumps(s, indent=2))
        return 0
    print(f"scene        {s['name']}  ({s['source']})")
    print(f"mesh         {s['vertices']} vertices, {s['triangles']} triangles"
          + (f" ({s['quads']} quads)" if s["quads"] else ""))
    print(f"bounds (m)   min {s['bounds_min']}  max {s['bounds_max']}")
    print(f"size (m)     {s['size']}   surface {s['surface_area_m2']} m^2")
    print(f"up axis      {_up_axis_line(s)}")
    print(f"appearance   {s['appearance']}" + (f" {s['texture_size'][0]}x{s['texture_size'][1]}"
                                               if "texture_size" in s else "")
          + (", normals" if s["normals"] else ""))
    if "free_space_error" in s:
        print(f"free volume  unknown: {s['free_space_error']}")
    elif s["enclosed"]:
        print(f"free volume  {s['free_volume_m3']:.2f} m^3 around the take-off point (enclosed)")
    else:
        print(f"free volume  {s['free_volume_m3']:.2f} m^3 around the take-off point, not enclosed: the surface is "
              f"open, so the room ends at the scan's bounds and holes up to {2 * HOLE_RADIUS:.1f} m across are closed")
    if "free_box" in s:
        print(f"free box     {s['free_box']}  (take-off column kept clear)")
    ceiling = (f"{s['ceiling_z']:.3f}" if s["ceiling_z"] is not None
               else f"none (workspace capped at planner.max_height {s['max_height']} m above the floor)")
    print(f"floor (m)    {s['floor_z']:.3f}   ceiling {ceiling}   (from {s['levels_from']})")
    print(f"workspace    min {s['workspace_min']}  max {s['workspace_max']}  (candidates keep "
          f"{s['required_clearance']:.2f} m inside it)")
    return 0


def _up_axis_line(s: dict) -> str:
    """One line: the file's up axis, how it was found and (under auto) how sure the estimate is."""
    est, mode = s.get("up_estimate"), s.get("up_axis_mode")
    rot = s.get("rotation_deg") or [0.0, 0.0, 0.0]
    turn = f", then rotated {rot} deg about x, y, z" if any(rot) else ""
    if mode == "vector":
        return f"file {s['file_up_axis']} -> world z (scene.up_vector){turn}"
    if mode != "auto" or not est:
        return f"file {s['file_up_axis']} -> world z{turn}"
    vec = "(" + ", ".join(f"{x:.2f}" for x in est["up"]) + ")"
    shares = (f"floor {est['floor_share']:.0%} + walls {est['wall_share']:.0%} of the area, "
              f"floor spread {est['floor_spread_deg']:.1f} deg")
    cues = est.get("cues") or {}
    if cues:
        named = [k for k, v in cues["axis"].items() if v == "up"]
        sign = ", ".join(f"{k} {v:+.2f}" for k, v in cues["sign"].items())
        shares += (f"; axis named by {', '.join(named)} of {len(cues['axis'])} cues, support surfaces "
                   f"{cues['support_share']:.1%} of the area, extent {cues['extent_m'][0]:.2f} m along it "
                   f"(others {cues['extent_m'][1]:.2f}, {cues['extent_m'][2]:.2f}); sign: {sign}")
    if est["confidence"] == "confident":
        return f"auto: file {est['snapped'] or vec} -> world z, confident ({shares}){turn}"
    return (f"auto: uncertain ({est['reason']}; estimate {vec}, {shares}): kept file z -> world z{turn}; "
            "set --up-axis/--up-vector (scene.up_axis, scene.up_vector)")


def _tour(args) -> int:
    from flightrecon.scenario import load_config
    from flightrecon.fileio import write_json
    from flightrecon.geometry import camera_pose
    from flightrecon.sim.camera import RGBDCamera
    from flightrecon.sim.world import build_world

    import cv2

    if args.views < 1:
        raise SceneError("--views must be at least 1")
    scene = _load(args)
    cfg = load_config(None, [f'scene.cache_dir="{args.cache_dir}"'] if args.cache_dir else [])
    world = build_world(scene, cfg, with_drone=False)
    cam = RGBDCamera(world, args.width, args.height, args.hfov, cfg.camera.near, cfg.camera.far)
    center = _viewpoint(scene)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    frames = []
    for i in range(args.views):
        yaw = 2 * math.pi * i / args.views
        T = camera_pose(center, yaw, args.pitch)
        rgb, depth = cam.render(T)
        cv2.imwrite(str(out / f"rgb_{i:03d}.png"), cv2.cvtColor((rgb * 255 + 0.5).astype(np.uint8), cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(out / f"depth_{i:03d}.png"), np.clip(depth * 1000 + 0.5, 0, 65535).astype(np.uint16))
        frames.append({"rgb": f"rgb_{i:03d}.png", "depth_mm": f"depth_{i:03d}.png", "T_wc": T.tolist()})
    write_json(out / "views.json", {"scene": scene.name, "K": cam.K.tolist(), "width": args.width,
                                    "height": args.height, "frames": frames})
    print(f"wrote {len(frames)} RGB-D views of {scene.name} to {out}")
    return 0


def _viewpoint(scene) -> np.ndarray:
    """The center of the scene's free take-off column, or 1.3 m above the middle of the floor."""
    if "free_box" in scene.meta:
        lo, hi = np.asarray(scene.meta["free_box"], float)
        return np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, min(hi[2], lo[2] + 1.0)])
    lo, hi = scene.bounds
    return np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2] + min(1.3, 0.5 * (hi[2] - lo[2]))])
