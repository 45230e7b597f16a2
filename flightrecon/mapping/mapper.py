"""Online 2DGS mapping: add a frame's new splats, then optimize on it and on replayed frames.

One `add_frame` is the paper's per-timestep update (Section III-B): gamma-rejected initialization
from the frame, K_new Adam iterations on it, then K_replay iterations each on a frame drawn at random
(seeded) from the earlier ones, uniformly or favouring those trained longest ago
(`MapperConfig.replay`). With `k_new_stop` > 0 (not the paper's setting) the K_new iterations end
once the frame's loss has fallen to that share of its first value (after `k_new_min`): a view the
map already explains needs few. With `replay_window` < 1 (not the paper's setting) each replay
iteration trains on a window of the replayed frame, drawn at random: the frame keeps its full
resolution while an iteration pays for a share of its pixels. With `replay_downsample` n > 1 (not
the paper's setting) each replay iteration trains on the whole frame at 1/n of its width and height
(frames.downsample), a window of it if both are set. With `skip_tiles` > 0 (not the paper's setting) an
iteration leaves out the frame's tiles that already match it (mapping/tile_skip.py).

Pruning (`prune_opacity` > 0) drops the splats whose opacity fell below it after the update,
every column with them (GaussianMap.keep: optimizer moments, reliability, the selectors'
columns). Their gamma voxels stay taken for the rejection of new splats ("tombstones"): the
optimizer found nothing to draw there, so a later frame does not seed a fresh splat in the place
of a pruned one, which would start with no evidence (and no training) where the map had both and
would make the prune-and-reseed cycle undo the pruning.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, fields

import numpy as np
import torch

from flightrecon import profiling
from flightrecon.config import MapperConfig
from flightrecon.errors import FlightReconError
from flightrecon.geometry import pixel_rays
from flightrecon.mapping import init as splat_init
from flightrecon.mapping.frames import (StoredFrame, Window, compact_frame, downsample, expand_frame,
                                        scaled_intrinsics, window_intrinsics)
from flightrecon.mapping.losses import ALPHA_MASK, FrameTarget, frame_target, training_loss
from flightrecon.mapping.optimizer import SparseAdam
from flightrecon.mapping.store import PARAM_SHAPES, GaussianMap
from flightrecon.mapping.tile_skip import tile_errors, tiles_to_keep
from flightrecon.mapping.voxel_hash import reject_near, voxel_keys
from flightrecon.render import RenderedView, candidate_rows, render, render_view_with_sums
from flightrecon.render.api import tile_pixels

log = logging.getLogger(__name__)

TRAIN_OUTPUTS = ("features", "alpha", "depth", "normal", "distortion")
_MIN_SCALE = 1e-3  # m; splats finer than a millimetre add nothing at our resolutions
REFERENCE_PIXELS = 640 * 480  # the paper's image size, where init_subsample is the share as given


@dataclass
class FrameStats:
    frame: int
    added: int
    total: int


def seed_share(cfg: MapperConfig, width: int, height: int) -> float:
    """Share of a frame's usable pixels that seed splats (see MapperConfig.init_scale_by_resolution).

    At 320x240 a pixel covers four times the surface it covers at 640x480, so the same share would
    seed a four times sparser map: on office0 that capped a single frame's fit at ~31 dB after 100
    iterations against ~40 dB with the density of 10% at 640x480.
    """
    if not cfg.init_scale_by_resolution:
        return cfg.init_subsample
    return min(1.0, cfg.init_subsample * REFERENCE_PIXELS / (width * height))


def default_device(backend: str) -> torch.device:
    """Where the map lives: the GPU when the rasterizer backend will be gsplat's CUDA one."""
    if backend == "cuda" and not torch.cuda.is_available():
        raise FlightReconError("mapper.backend = cuda, but torch sees no CUDA device (a CPU build of torch, "
                               "or no GPU): use mapper.backend = auto or cpu")
    if backend == "cuda" or (backend == "auto" and torch.cuda.is_available()):
        return torch.device("cuda")
    return torch.device("cpu")


class OnlineMapper:
    """The 2DGS map, its optimizer and its replay frames; feed it frames in capture order."""

    def __init__(self, cfg: MapperConfig, *, near: float = 0.05, far: float = 10.0, seed: int = 0,
                 device: str | torch.device | None = None) -> None:
        self.cfg = cfg
        self.near, self.far = float(near), float(far)
        self.device = torch.device(device) if device is not None else default_device(cfg.backend)
        self.map = GaussianMap(device=self.device)
        self.adam = SparseAdam(self.map, {
            "means": cfg.lr_means, "quats": cfg.lr_rotations, "log_scales": cfg.lr_scales,
            "opacity_logits": cfg.lr_opacities, "colors": cfg.lr_colors})
        self.frames: list[StoredFrame] = []
        self.last_trained: list[int] = []  # per stored frame, the optimization call that last trained it
        self._clock = 0  # optimization calls so far (a frame's K_new counts as one)
        self.rng = np.random.default_rng(seed)
        self._rays: dict[tuple, torch.Tensor] = {}
        self.tombstones = np.zeros(0, np.int64)  # sorted gamma-voxel keys of pruned splats
        self.pruned = 0
        self.tile_error: list[np.ndarray | None] = []  # per stored frame: its tiles' errors when last rendered
        self.frame_iterations: list[int] = []  # per stored frame: the iterations trained on it

    # -- one timestep ---------------------------------------------------------------------------
    def add_frame(self, rgb: np.ndarray, depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray) -> FrameStats:
        """Insert new splats from the frame and run K_new + K_replay iterations."""
        with profiling.stage("add_frame"):
            return self._add_frame(rgb, depth, K, T_wc)

    def _add_frame(self, rgb: np.ndarray, depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray) -> FrameStats:
        index = len(self.frames)
        depth = np.asarray(depth, np.float32)
        valid = splat_init.valid_depth_mask(depth, self.near, self.far)
        if not valid.any():
            log.warning("frame %d has no valid depth in (%.3g, %.3g] m: skipped", index, self.near, self.far)
            return FrameStats(index, 0, len(self.map))
        frame = compact_frame(rgb, depth, K, T_wc, valid)
        self.frames.append(frame)
        self.tile_error.append(None)
        self.frame_iterations.append(0)
        with profiling.stage("densify"):
            added = self._insert(rgb, depth, K, T_wc, index)
        self._optimize(index, self.cfg.k_new, count_observed=True, stop_share=self.cfg.k_new_stop,
                       min_iters=self.cfg.k_new_min)
        self._clock += 1
        self.last_trained.append(self._clock)
        self._replay(index, self.cfg.k_replay)
        with profiling.stage("prune"):
            self._prune()
        return FrameStats(index, added, len(self.map))

    def refine(self, iterations: int) -> None:
        """`iterations` replay iterations over every stored frame, drawn per `cfg.replay`, and no new
        frame: how far the flight's views could take the map with a larger mapping budget."""
        if iterations < 0:
            raise ValueError(f"refine: iterations must be >= 0, got {iterations}")
        if not self.frames:
            return
        self._replay(len(self.frames), iterations)
        self._prune()

    def _replay(self, index: int, iterations: int) -> None:
        """One iteration on each of `iterations` frames before `index`, drawn by `_replay_pick`."""
        for _ in range(iterations):
            pick = self._replay_pick(index)
            self._clock += 1
            self.last_trained[pick] = self._clock
            self._optimize(pick, 1, window=self._replay_window(self.frames[pick]),
                           factor=self.cfg.replay_downsample)

    def _prune(self) -> None:
        """Drop the splats below `prune_opacity` (all columns) and keep their voxels taken; off at 0."""
        if self.cfg.prune_opacity <= 0:
            return
        drop = torch.sigmoid(self.map["opacity_logits"]) < self.cfg.prune_opacity
        count = int(drop.sum())
        if count == 0:
            return
        keys = voxel_keys(self.map["means"][drop].detach().cpu().numpy(), self.cfg.gamma)
        self.tombstones = np.union1d(self.tombstones, keys)
        self.map.keep(~drop)
        self.pruned += count

    def _replay_pick(self, index: int) -> int:
        """A frame before `index` to replay (frame 0 when it is the only one), drawn per `cfg.replay`.

        Training one view blurs the detail its neighbours fitted (on office0, a frame loses ~1.6 dB
        between its own update and the end of the survey), so "stale" draws the frames whose last
        training lies furthest back: weight 1 + optimization calls since then.
        """
        if index == 0:
            return 0
        if self.cfg.replay == "uniform":
            return int(self.rng.integers(index))
        weight = 1.0 + self._clock - np.asarray(self.last_trained[:index], np.float64)
        return int(self.rng.choice(index, p=weight / weight.sum()))

    def _replay_window(self, frame: StoredFrame) -> Window | None:
        """A window of `replay_window` of the width and height of the frame as replayed (at 1/
        `replay_downsample`) at a random place; None: all of it."""
        share = self.cfg.replay_window
        if share >= 1.0:
            return None
        H, W = (n // self.cfg.replay_downsample for n in frame.rgb.shape[:2])
        w, h = max(1, round(W * share)), max(1, round(H * share))
        return Window(int(self.rng.integers(W - w + 1)), int(self.rng.integers(H - h + 1)), w, h)

    def _insert(self, rgb: np.ndarray, depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray, index: int) -> int:
        share = seed_share(self.cfg, depth.shape[1], depth.shape[0])
        eligible = self._unexplained(rgb, depth, K, T_wc) if index > 0 and self.cfg.seed_where == "unexplained" \
            else None
        cand = splat_init.frame_candidates(rgb, depth, K, T_wc, near=self.near, far=self.far,
                                           subsample=share, rng=self.rng,
                                           edges=self.cfg.init_edge_normals, eligible=eligible)
        if index > 0:  # the first frame is inserted whole (2DGS-SLAM)
            keep = reject_near(cand["points"], self.map["means"].cpu().numpy(), self.cfg.gamma,
                               self.cfg.one_new_per_voxel, blocked=self.tombstones)
            cand = {k: v[keep] for k, v in cand.items()}
        if len(cand["points"]) == 0:
            return 0
        params = splat_init.splat_params(cand["points"], cand["normals"], cand["colors"],
                                         opacity=self.cfg.init_opacity, min_scale=_MIN_SCALE,
                                         max_scale=self.cfg.gamma)
        self.map.append(frame=index, **{k: torch.from_numpy(v) for k, v in params.items()})
        return len(cand["points"])

    def _unexplained(self, rgb: np.ndarray, depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray) -> np.ndarray:
        """Pixels [H, W] the map rendered from the new frame's pose does not explain yet: not opaque, or
        depth or color off by more than the config's tolerances. Only these seed (seed_where)."""
        out = self.render_view(T_wc, K, depth.shape[1], depth.shape[0])
        alpha = out.alpha[0, ..., 0].cpu().numpy()
        rendered_depth = out.depth[0, ..., 0].cpu().numpy()
        color_error = np.abs(out.features[0].cpu().numpy() - np.asarray(rgb, np.float32)[..., :3]).mean(-1)
        with np.errstate(invalid="ignore"):
            explained = ((alpha >= ALPHA_MASK)
                         & (np.abs(rendered_depth - depth) <= self.cfg.seed_depth_tol * depth)
                         & (color_error <= self.cfg.seed_color_tol))
        return ~explained

    def _optimize(self, index: int, iters: int, count_observed: bool = False, stop_share: float = 0.0,
                  min_iters: int = 0, window: Window | None = None, factor: int = 1) -> None:
        """`iters` Adam iterations on stored frame `index` (at 1/`factor` of its size, or on a `window`
        of that), on the splats that may reach that image; with `stop_share` > 0, fewer once (after
        `min_iters`) the loss of an iteration that renders every tile is at most that share of the first.

        Only splats the camera can see get gradient and updates, and the rest stay fixed during the
        call, so one conservative culling test at the start (_view_rows) picks every splat that could
        touch the image in any iteration; the iterations train a gathered copy of those rows (in id order, so
        the rasterizer's depth ties break alike) and write it back once, so the per-iteration cost
        scales with the view instead of the map. Only the parameters are copied: the optimizer keeps
        the moments in the map and updates them at `rows`. Renders, gradients and updates are a
        full-map run's but for last-bit rounding: torch computes the last few elements of an
        elementwise op (the sigmoid) with its scalar formula, so a splat's rounding can depend on
        its position."""
        if iters <= 0 or len(self.map) == 0:
            return
        frame = self.frames[index]
        whole = window is None and factor == 1  # tiles are left out of whole-frame iterations only
        with profiling.stage("view setup"):
            target = self._target(frame, window, factor)
            H, W = target.depth.shape[:2]
            viewmat = frame.viewmat.to(self.device)[None]
            K = scaled_intrinsics(frame.K, factor)
            Ks = (K if window is None else window_intrinsics(K, window)).to(self.device)[None]
            rows = self._view_rows(viewmat[0], Ks[0], W, H)
            if len(rows) == 0:
                return
            leaves = self.adam.gather(rows)
        first_loss = None
        for it in range(iters):
            keep = self._tiles_to_render(index) if whole else None
            keep_tiles = None if keep is None else torch.from_numpy(keep)[None].to(self.device)
            with profiling.stage("render"):
                out = self._render(leaves, viewmat, Ks, W, H, TRAIN_OUTPUTS, keep_tiles)
            with profiling.stage("loss"):
                loss = self._loss(out, target, None if keep is None else tile_pixels(keep_tiles, W, H)[0])
                if whole and self.cfg.skip_tiles > 0:
                    self._note_tile_errors(index, out.features[0], target.rgb, keep)
            with profiling.stage("backward"):
                loss.backward()
            with profiling.stage("optimizer step"):
                visible = torch.nonzero(out.radii[0] > 0, as_tuple=True)[0]
                if count_observed and it == 0:
                    self.map["n_observed"][rows[visible]] += 1
                self.adam.step(leaves, visible, rows)
            if stop_share > 0 and keep is None:  # the loss before this step, against the first one's
                value = float(loss.detach())
                first_loss = value if first_loss is None else first_loss
                if it + 1 >= min_iters and value <= stop_share * first_loss:
                    break
        with profiling.stage("view setup"):
            self.adam.scatter(rows, leaves)

    def _tiles_to_render(self, index: int) -> np.ndarray | None:
        """The tiles the next iteration on stored frame `index` renders (bool [rows, cols]), or None for
        all of them: always without skip_tiles, before the frame was ever rendered, and on every
        skip_full_every-th iteration on it. Counts the iteration."""
        n = self.frame_iterations[index]
        self.frame_iterations[index] = n + 1
        errors = self.tile_error[index]
        if self.cfg.skip_tiles <= 0 or errors is None or n % self.cfg.skip_full_every == 0:
            return None
        return tiles_to_keep(errors, self.cfg.skip_tiles)

    def _note_tile_errors(self, index: int, color: torch.Tensor, target: torch.Tensor, keep: np.ndarray | None) -> None:
        """Store the rendered tiles' errors of stored frame `index`; a tile left out keeps its old one."""
        errors = tile_errors(color, target)
        if keep is None:
            self.tile_error[index] = errors
        else:
            self.tile_error[index][keep] = errors[keep]

    def _view_rows(self, viewmat: torch.Tensor, K: torch.Tensor, W: int, H: int) -> torch.Tensor:
        """Increasing indices of the splats one camera may draw: the C++ kernel's own culling test on
        a CPU map (cpu and reference backends), every splat on a GPU map."""
        if self.device.type != "cpu":
            return torch.arange(len(self.map), device=self.device)
        return candidate_rows(self.map["means"], self.map["quats"], self.map["log_scales"], viewmat, K, W, H,
                              self.near, self.far)

    # -- checkpoints ----------------------------------------------------------------------------
    def get_state(self) -> dict:
        """Everything carried between frames, for flightrecon.checkpoint: the map with its optimizer
        moments and step counts (map columns), the replay frames and their training clock, the
        seeding and replay RNG, and the pruning tombstones. The rest is rebuilt from the config."""
        return {"map": self.map.get_state(),
                "frames": [{f.name: getattr(frame, f.name) for f in fields(StoredFrame)} for frame in self.frames],
                "last_trained": list(self.last_trained), "clock": self._clock,
                "rng": self.rng.bit_generator.state, "tombstones": self.tombstones.copy(), "pruned": self.pruned,
                "frame_iterations": list(self.frame_iterations),
                "tile_error": [np.zeros((0, 0)) if e is None else e.copy() for e in self.tile_error]}

    def set_state(self, state: dict) -> None:
        """Continue from a `get_state()` snapshot (of a mapper built with the same config)."""
        self.map.set_state(state["map"])
        self.frames = [StoredFrame(**frame) for frame in state["frames"]]
        self.last_trained = [int(t) for t in state["last_trained"]]
        self._clock = int(state["clock"])
        self.rng.bit_generator.state = state["rng"]
        self.tombstones = np.asarray(state["tombstones"], np.int64)
        self.pruned = int(state["pruned"])
        # checkpoints from before skip_tiles carry neither: no frame has tile errors yet
        self.frame_iterations = [int(n) for n in state.get("frame_iterations", [0] * len(self.frames))]
        self.tile_error = [None if np.size(e) == 0 else np.array(e, np.float64)
                           for e in state.get("tile_error", [np.zeros((0, 0))] * len(self.frames))]

    # -- queries --------------------------------------------------------------------------------
    def _render(self, p: dict[str, torch.Tensor], viewmats: torch.Tensor, Ks: torch.Tensor, W: int, H: int,
                outputs: tuple[str, ...], keep_tiles: torch.Tensor | None = None):
        return render(p["means"], p["quats"], p["log_scales"], p["opacity_logits"],
                      p["colors"], viewmats, Ks, W, H, near=self.near, far=self.far, outputs=outputs,
                      backend=self.cfg.backend, keep_tiles=keep_tiles)

    def splats(self) -> dict[str, torch.Tensor]:
        """The current splat parameters with unit quaternions, as renders of the whole map take them."""
        p = {name: self.map[name] for name in PARAM_SHAPES}
        p["quats"] = torch.nn.functional.normalize(p["quats"], dim=-1)
        return p

    def render_capture(self, T_wc: np.ndarray, K: np.ndarray, width: int, height: int) -> RenderedView:
        """The map at a captured pose after mapping (color, alpha, depth, normal), kept with the graph that
        gives per-splat pixel sums: the one render of that pose the loop's consumers share."""
        p = self.splats()
        # inverted in float32 by torch, as the selectors' reliability update always did
        viewmat = torch.linalg.inv(torch.as_tensor(np.asarray(T_wc, np.float32), device=self.device))
        Kt = torch.as_tensor(np.asarray(K, np.float32), device=self.device)
        return render_view_with_sums(p["means"], p["quats"], p["log_scales"], p["opacity_logits"], p["colors"],
                                     viewmat, Kt, width, height, near=self.near, far=self.far,
                                     outputs=("features", "alpha", "depth", "normal"), backend=self.cfg.backend)

    @torch.no_grad()
    def render_view(self, T_wc: np.ndarray, K: np.ndarray, width: int, height: int,
                    outputs: tuple[str, ...] = ("features", "alpha", "depth")):
        """Render the current map from camera-to-world `T_wc` (one camera)."""
        p = {name: self.map[name] for name in PARAM_SHAPES}
        viewmat = torch.as_tensor(np.linalg.inv(T_wc), dtype=torch.float32, device=self.device)[None]
        Ks = torch.as_tensor(K, dtype=torch.float32, device=self.device)[None]
        return self._render(p, viewmat, Ks, width, height, outputs)

    @torch.no_grad()
    def frame_loss(self, index: int) -> float:
        """Training loss of stored frame `index` under the current map (for tests and logs)."""
        f = self.frames[index]
        target = self._target(f)
        H, W = target.depth.shape[:2]
        p = {name: self.map[name] for name in PARAM_SHAPES}
        out = self._render(p, f.viewmat.to(self.device)[None], f.K.to(self.device)[None], W, H, TRAIN_OUTPUTS)
        return float(self._loss(out, target))

    def _loss(self, out, target: FrameTarget, keep: torch.Tensor | None = None) -> torch.Tensor:
        c = self.cfg
        return training_loss(out, target, ssim_weight=c.ssim_weight, lambda_depth=c.lambda_depth,
                             lambda_normal=c.lambda_normal, lambda_distortion=c.lambda_distortion, keep=keep)

    def _target(self, frame: StoredFrame, window: Window | None = None, factor: int = 1) -> FrameTarget:
        rgb, depth = downsample(*expand_frame(frame, self.device), factor)
        rays = self._rays_for(depth.shape[1], depth.shape[0], scaled_intrinsics(frame.K, factor))
        if window is not None:
            rgb, depth, rays = (image[window.rows, window.cols] for image in (rgb, depth, rays))
        return frame_target(rgb, depth, rays, with_ssim=self.cfg.ssim_weight > 0)

    def _rays_for(self, W: int, H: int, K: torch.Tensor) -> torch.Tensor:
        key = (W, H, *K.flatten().tolist())
        if key not in self._rays:
            self._rays[key] = torch.as_tensor(pixel_rays(W, H, K.double().numpy()), dtype=torch.float32,
                                              device=self.device)
        return self._rays[key]