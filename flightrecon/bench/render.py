"""2DGS rasterizer speed: C++ cpu backend vs the vectorized torch reference on a realistic map
(and, with `--backends cpu,cuda` on a GPU machine, gsplat's cuda backend on the same map and cameras).

The map stands in for one the online mapper builds from RGB-D frames: splats sampled on the surfaces
of a procedural scene (area-weighted, so spacing is uniform: sqrt(area / N), 4 cm for 200k splats
in office0), each oriented by its face normal, colored from the mesh, scaled to the spacing (the
mapper's nearest-neighbour rule) with opacity 0.7. Workloads: forward and forward+backward of the
mapping outputs (RGB, alpha, depth, normal, distortion) at 640x480 and 160x120, and the
view-selection batch (198 cameras, one per-camera channel, 160x120, forward only). The reference
is dense (every splat against every pixel), so it runs on a downscaled copy of the same camera and
its time is scaled linearly in pixels to the full size (reported both ways). Medians over repeats;
cuda timings wait for the device (torch.cuda.synchronize) and have no reference or kernel profile rows.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from flightrecon import profiling
from flightrecon.bench.common import report, time_call
from flightrecon.errors import FlightReconError
from flightrecon.geometry import camera_pose, intrinsics, invert_pose
from flightrecon.render import render
from flightrecon.render.extension import load

MAPPING = ("features", "alpha", "depth", "normal", "distortion")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scene", default="office0", help="procedural scene to sample splats from")
    p.add_argument("--sizes", default="50000,200000", help="splat counts, comma separated")
    p.add_argument("--repeat", type=int, default=5, help="timed repeats per row (median reported)")
    p.add_argument("--batch", type=int, default=198, help="cameras in the view-selection batch")
    p.add_argument("--ref-pixels", type=int, default=1200,
                   help="pixels of the downscaled image the dense reference renders")
    p.add_argument("--backends", default="cpu",
                   help="comma separated: cpu (with the dense reference as its peer), cuda (gsplat; needs a GPU)")


def surface_splats(scene_name: str, n: int, seed: int = 0) -> list[torch.Tensor]:
    """n splats on the scene's surfaces: means, quats, log_scales, opacity_logits, colors."""
    from flightrecon.scene.procedural import make_scene

    scene = make_scene(scene_name, seed)
    rng = np.random.default_rng(seed)
    tri = scene.vertices[scene.faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    fi = rng.choice(len(area), n, p=area / area.sum())
    r1, r2 = np.sqrt(rng.random(n)), rng.random(n)
    t = tri[fi]
    pts = (1 - r1)[:, None] * t[:, 0] + (r1 * (1 - r2))[:, None] * t[:, 1] + (r1 * r2)[:, None] * t[:, 2]
    nrm = cross[fi] / (np.linalg.norm(cross[fi], axis=1, keepdims=True) + 1e-12)
    # quaternion (w,x,y,z) turning +z onto the normal (half-way construction)
    q = np.concatenate([(1 + nrm[:, 2])[:, None], -nrm[:, 1:2], nrm[:, 0:1], np.zeros((n, 1))], 1)
    q[1 + nrm[:, 2] < 1e-6] = [0.0, 1.0, 0.0, 0.0]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    spacing = float(np.sqrt(area.sum() / n))
    colors = scene.vertex_colors[scene.faces[fi, 0]] / 255.0
    f32 = lambda a: torch.tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
    return [f32(pts), f32(q), torch.full((n, 2), float(np.log(spacing))),
            torch.full((n,), float(np.log(0.7 / 0.3))), f32(colors)]


def _camera(width: int, height: int, position=(0.0, 0.0, 1.5), yaw=0.3):
    vm = torch.tensor(invert_pose(camera_pose(np.array(position), yaw)), dtype=torch.float32)[None]
    K = torch.tensor(intrinsics(width, height, 90.0), dtype=torch.float32)[None]
    return vm, K


def _batch_cameras(scene_name: str, count: int, width: int, height: int, seed: int = 1):
    from flightrecon.scene.procedural import make_scene

    box = np.array(make_scene(scene_name, 0).meta["free_box"])
    rng = np.random.default_rng(seed)
    pos = box[0] + rng.random((count, 3)) * (box[1] - box[0])
    yaw = rng.uniform(-np.pi, np.pi, count)
    vm = torch.stack([torch.tensor(invert_pose(camera_pose(p, y)), dtype=torch.float32) for p, y in zip(pos, yaw)])
    K = torch.tensor(intrinsics(width, height, 90.0), dtype=torch.float32).repeat(count, 1, 1)
    return vm, K


def _fwd(splats, vm, K, w, h, outputs, backend="cpu"):
    with torch.no_grad():
        out = render(*splats, vm, K, w, h, outputs=outputs, backend=backend)
    if backend == "cuda":
        torch.cuda.synchronize()  # time the kernels, not their launch
    return out


def _fwd_bwd(splats, vm, K, w, h, backend="cpu"):
    ps = [t.clone().requires_grad_(True) for t in splats]
    out = render(*ps, vm, K, w, h, outputs=MAPPING, backend=backend)
    sum(getattr(out, k).sum() for k in MAPPING).backward()
    if backend == "cuda":
        torch.cuda.synchronize()


def _backends(spec: str) -> list[str]:
    names = [b.strip() for b in spec.split(",") if b.strip()]
    bad = [b for b in names if b not in ("cpu", "cuda")]
    if bad or not names:
        raise FlightReconError(f"bench render: --backends {spec!r}: choose from cpu, cuda (comma separated)")
    if "cuda" in names and not torch.cuda.is_available():
        raise FlightReconError("bench render: --backends cuda needs a CUDA device, and torch sees none")
    return names


def _stats_row(label: str, stats: dict, threads: int, pixels: int, ceiling: dict) -> dict:
    row = {"row": label}
    row.update({k: round(v * 1e3, 2) for k, v in stats.items() if k.endswith("_s")})
    # camera-parallel runs report thread-seconds; tile-parallel runs report wall time on all threads
    cores = 1 if stats.get("by_camera") else threads
    row["timing"] = "thread-ms summed" if stats.get("by_camera") else "wall ms"
    if stats.get("evals"):
        prof = profiling.StageProfile()
        prof.add_kernel("forward", stats)
        rates = profiling.blend_rates(prof, ceiling, cores)
        row.update({"evals_M": round(stats["evals"] / 1e6, 1),
                    "blend_M_per_s_core": round(rates["evals_M_per_s_thread"], 1),
                    "of_ceiling": round(rates["of_ceiling"], 3),
                    "useful_of_ceiling": round(rates["useful_of_ceiling"], 3),
                    # evaluated vs blending (alpha >= 1/255, pixel not terminated) splats per pixel:
                    # the gap is the work the tile/row/8-column-group visiting order wastes
                    "evals_per_px": round(stats["evals"] / pixels, 1),
                    "blends_per_px": round(stats.get("blends", 0) / pixels, 1)})
    return row


def run(args) -> dict:
    backends = _backends(args.backends)
    ext = load()
    threads = ext.num_threads()
    ceiling = ext.blend_ceiling(1.0)
    rows, profile = [], []
    for n in [int(s) for s in args.sizes.split(",")]:
        host_splats = surface_splats(args.scene, n)
        for b in backends:
            _run_backend(args, b, n, host_splats, ext, threads, rows, profile, ceiling)
    targets = {"640x480 200k forward": "<= 100 ms", "640x480 200k forward+backward": "<= 300 ms",
               "198-camera batch 160x120": "<= 300 ms", "vs reference": ">= 50x"}
    report("render", rows, args.out, extra={"profile_ms": profile, "targets": targets,
                                            "omp_threads": threads, "ceiling": ceiling})
    report("render-profile", profile)
    return {"rows": rows, "profile": profile}


def _run_backend(args, backend: str, n: int, host_splats, ext, threads: int, rows: list, profile: list,
                 ceiling: dict) -> None:
    """One backend's rows for one map size; the cpu backend also its kernel profile and reference peer."""
    dev = "cuda" if backend == "cuda" else "cpu"
    cpu = backend == "cpu"
    splats = [t.to(dev) for t in host_splats]
    for (w, h) in ((640, 480), (160, 120)):
        vm, K = (x.to(dev) for x in _camera(w, h))
        t = time_call(lambda: _fwd(splats, vm, K, w, h, MAPPING, backend), repeat=args.repeat)
        if cpu:
            profile.append(_stats_row(f"{n} {w}x{h} forward", ext.last_stats(), threads, w * h, ceiling))
        rows.append({"backend": backend, "splats": n, "image": f"{w}x{h}", "workload": "forward",
                     "ms": t["median_s"] * 1e3})
        tb = time_call(lambda: _fwd_bwd(splats, vm, K, w, h, backend), repeat=args.repeat)
        if cpu:
            profile.append(_stats_row(f"{n} {w}x{h} backward", ext.last_stats(), threads, w * h, ceiling))
        rows.append({"backend": backend, "splats": n, "image": f"{w}x{h}", "workload": "forward+backward",
                     "ms": tb["median_s"] * 1e3})
        if not cpu:
            continue
        # dense reference on a downscaled copy of the same camera, scaled back linearly in pixels
        s = max(1, int(round((w * h / args.ref_pixels) ** 0.5)))
        rw, rh = w // s, h // s
        Kr = K.clone()
        Kr[:, :2] /= s
        tr = time_call(lambda: _fwd(splats, vm, Kr, rw, rh, MAPPING, "reference"), repeat=1, warmup=0)
        tc = time_call(lambda: _fwd(splats, vm, Kr, rw, rh, MAPPING), repeat=args.repeat)
        scaled = tr["median_s"] * (w * h) / (rw * rh)
        rows.append({"backend": backend, "splats": n, "image": f"{w}x{h}",
                     "workload": f"reference forward ({rw}x{rh} run, scaled)",
                     "ms": scaled * 1e3, "speedup_vs_ref": scaled / t["median_s"],
                     "speedup_same_size": tr["median_s"] / tc["median_s"]})
    vm, K = (x.to(dev) for x in _batch_cameras(args.scene, args.batch, 160, 120))
    g = torch.Generator().manual_seed(0)
    per_cam = torch.rand(args.batch, n, 1, generator=g).to(dev)
    batch_splats = splats[:4] + [per_cam]
    t = time_call(lambda: _fwd(batch_splats, vm, K, 160, 120, ("features",), backend), repeat=args.repeat)
    if cpu:
        profile.append(_stats_row(f"{n} 160x120 x{args.batch} batch", ext.last_stats(), threads,
                                  args.batch * 160 * 120, ceiling))
    rows.append({"backend": backend, "splats": n, "image": "160x120",
                 "workload": f"{args.batch}-camera 1-channel batch", "ms": t["median_s"] * 1e3})
