"""The paper's baselines as view selectors (their papers and public code; docs/architecture.md, "Selectors").

All of them share our online 2DGS mapper, our planner and our candidate library (the loop hands
every selector the same feasible candidates), so a comparison isolates the selection criterion.
Per-splat state lives in the map columns each selector declares, so it stays aligned with the
splats through growth and pruning. None of them keeps 2D reliability, so none has a stopping
statistic and the stopping rule does not apply to them.

- `gaussmi` (Xie and Pan, RSS 2025): four world-horizontal reliability log-odds per splat
  [+x, +y, -x, -y], updated from its loss image L = 0.95 |I - I_obs| + 0.05 |D_acc - D_obs|; view
  score = sum_p sum_i w_i(p) g_i with g_i = sum_k c_ik (-ln P_ik), times (1 - revisit discount).
  docs/baselines.md lists what follows its public code and the one departure (no transmittance
  gate in the evidence sum, which our rasterizer does not expose per splat and pixel).
- `fisherrf` (Jiang et al., ECCV 2024): score = sum_theta H_cand / (H_train + lambda) with the
  rasterizer's squared-contribution diagonal Hessian (position, color, scale, opacity); H_train
  sums over all frames collected so far and is recomputed at each selection (one view is chosen
  per step, so greedy batch acquisition reduces to the argmax). Both at the scoring resolution.
- `activegs` (Jin et al., RA-L 2025): surfel confidence, a 0.2 m voxel map over the scene's box
  with visibility by projected voxel centers, the exploration utility (unexplored voxels in front of
  the rendered map), the confidence-weighted exploitation utility (a pixel without surface is worth
  0.5), and the path-length term, on our shared candidate library; the path length is the planned
  trajectory's. `activegs_native` (active/activegs_native.py) flies it with its own candidates.
  docs/baselines.md lists what follows its public code and where it departs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from flightrecon.active.candidate_views import render_candidates
from flightrecon.active.protocol import MapView, Observation, Selector, capture_view, float_tensor, scoring_intrinsics
from flightrecon.active.reliability import observation_weights, splat_normals
from flightrecon.config import ScenarioConfig, option
from flightrecon.geometry import pixel_rays, yaw_of_camera
from flightrecon.render import FisherDiag, render_fisher_diag

EXPLORE_RANGE = 5.0  # m, ActiveGS's utility range
# GauSS-MI's constants (its public configs and code, docs/baselines.md)
GAUSSMI_RGB_WEIGHT = 0.95  # loss_rgb_alpha
GAUSSMI_MIN_LOSS = 1e-4  # reli_min_loss
GAUSSMI_CLAMP = 10.0  # log-odds clip of input_logodds
GAUSSMI_MIN_WEIGHT = 1.0  # our stand-in for reli_touch_threshold (5 pixels with transmittance > 0.8)
GAUSSMI_DISCOUNT = 0.95  # pre_discount_coeff
GAUSSMI_FREE_VIEWS = 5  # no revisit discount while at most this many viewpoints were taken
GAUSSMI_KEPT_VIEWS = 100  # max_num_previous_vps


@dataclass(frozen=True)
class GaussMIConfig:
    """`[gaussmi]`: GauSS-MI's tuned weights (its public configs)."""

    lambda_L: float = option(1.7, 1e-6, 1e6, doc="loss-image scale")
    lambda_T: float = option(10.0, 0.0, 1e6, doc="evidence weight")
    moved_from = {"baselines.gaussmi_lambda_L": "lambda_L", "baselines.gaussmi_lambda_T": "lambda_T"}


@dataclass(frozen=True)
class FisherRFConfig:
    """`[fisherrf]`: FisherRF's Hessian regularizer."""

    regularizer: float = option(1e-6, 0.0, 1e3, doc="lambda added to the training views' Hessian diagonal")
    moved_from = {"baselines.fisherrf_lambda": "regularizer"}


@dataclass(frozen=True)
class ActiveGSConfig:
    """`[activegs]`: ActiveGS's exploration grid and path term (activegs and activegs_native)."""

    voxel: float = option(0.2, 0.02, 2.0, doc="exploration voxel size (m)")
    extent: list = option([16.0, 16.0, 5.0], doc="voxel grid size around the first camera (m), only for a "
                          "selector driven without a scene; in a flight its grid spans the scene")
    path_weight: float = option(0.5, 0.0, 100.0, doc="path-length term weight")
    explore_weight: float = option(1000.0, 0.0, 1e6, doc="weight of the exploration utility against the "
                                   "exploitation one (ActiveGS's code: 1000)")
    moved_from = {"baselines.activegs_voxel": "voxel", "baselines.activegs_extent": "extent",
                  "baselines.activegs_path_weight": "path_weight"}


class _Scoring(Selector):
    """Shared: the scoring intrinsics of the config's camera at the selector's scoring resolution."""

    role = "baseline"

    def __init__(self, cfg: ScenarioConfig, width: int | None = None, height: int | None = None) -> None:
        super().__init__(cfg)
        self.width, self.height = width or cfg.selector.scoring_width, height or cfg.selector.scoring_height
        self.K_score = scoring_intrinsics(cfg, self.width, self.height)


# ---------------------------------------------------------------------------------- GauSS-MI
def direction_weights(means: torch.Tensor, centers: torch.Tensor) -> torch.Tensor:
    """c [C,N,4] = [max(dx,0), max(dy,0), max(-dx,0), max(-dy,0)] of d = (mu - c)/|mu - c|."""
    d = torch.nn.functional.normalize(means[None] - centers[:, None, :], dim=-1)
    dx, dy = d[..., 0], d[..., 1]
    return torch.stack([dx.clamp_min(0), dy.clamp_min(0), (-dx).clamp_min(0), (-dy).clamp_min(0)], -1)


def gaussmi_loss_image(color: torch.Tensor, accumulated_depth: torch.Tensor, rgb_obs: torch.Tensor,
                       depth_obs: torch.Tensor) -> torch.Tensor:
    """L [H,W] = 0.95 mean_rgb |I - I_obs| + 0.05 |D - D_obs| (GauSS-MI's loss image), D the
    accumulated depth sum_i w_i z_i (not divided by alpha, as its rasterizer outputs it); the color
    term where the observed color sums above 0.01, the depth term where the observed depth exceeds
    0.01 m (its masks)."""
    rgb_mask = rgb_obs.sum(-1) > 0.01
    depth_mask = depth_obs[..., 0] > 0.01
    l1_rgb = torch.where(rgb_mask, (color - rgb_obs).abs().mean(-1), 0.0)
    l1_depth = torch.where(depth_mask, (accumulated_depth - depth_obs).abs()[..., 0], 0.0)
    return GAUSSMI_RGB_WEIGHT * l1_rgb + (1 - GAUSSMI_RGB_WEIGHT) * l1_depth


def gaussmi_evidence(L: torch.Tensor, lambda_L: float) -> torch.Tensor:
    """Per-pixel log-odds evidence -ln(max(lambda_L L, 1e-4)): positive where the map fits
    (lambda_L L < 1), negative where it does not."""
    return -torch.log((lambda_L * L).clamp_min(GAUSSMI_MIN_LOSS))


def gaussmi_logodds_update(logodds: torch.Tensor, c: torch.Tensor, sums: torch.Tensor, touch: torch.Tensor,
                           lambda_T: float) -> torch.Tensor:
    """New log-odds [N,4]: l + clip(clip(lambda_T c_ik S_i, +-100), +-10), then clip(+-10). The two
    inner clips are its backend's and its `input_logodds`'; splats with `touch` False keep theirs."""
    delta = (lambda_T * c * sums[:, None]).clamp(-100.0, 100.0).clamp(-GAUSSMI_CLAMP, GAUSSMI_CLAMP)
    delta = torch.where(touch[:, None], delta, 0.0)
    return (logodds + delta).clamp(-GAUSSMI_CLAMP, GAUSSMI_CLAMP)


def gaussmi_gain(logodds: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """g [C,N] = sum_k c_ik (-ln P_ik), P = sigmoid(l) clamped to [1e-4, 0.9999]."""
    P = torch.sigmoid(logodds).clamp(1e-4, 0.9999)
    return (c * (-torch.log(P))[None]).sum(-1)


def revisit_discount(position: np.ndarray, yaw: float, visited: list[tuple[np.ndarray, float]]) -> float:
    """GauSS-MI's `inPreviousVps`: 0 while at most 5 viewpoints were taken; else walk the stored
    viewpoints from the second-newest back to the second-oldest with a discount starting at 0.95 and
    multiplied by 0.95 per step, and return it at the first within 0.3 m and 10 deg yaw; 0 if none.
    `visited` holds (position, yaw) in capture order, the newest (the current pose) last."""
    if len(visited) <= GAUSSMI_FREE_VIEWS:
        return 0.0
    disc = GAUSSMI_DISCOUNT
    for p, y in visited[-2:0:-1]:
        dyaw = abs((yaw - y + math.pi) % (2 * math.pi) - math.pi)
        if np.linalg.norm(position - p) < 0.3 and dyaw < math.radians(10.0):
            return disc
        disc *= GAUSSMI_DISCOUNT
    return 0.0


class GaussMISelector(_Scoring):
    """GauSS-MI (Xie and Pan, RSS 2025): four world-horizontal reliabilities per splat."""

    name = "gaussmi"
    section, settings = "gaussmi", GaussMIConfig
    COLUMN = "gaussmi_logodds"
    columns = {COLUMN: (4,)}  # world-horizontal log-odds [+x, +y, -x, -y]

    def __init__(self, cfg: ScenarioConfig) -> None:
        super().__init__(cfg)
        self.visited: list[tuple[np.ndarray, float]] = []

    @torch.no_grad()
    def observe(self, view: MapView, obs: Observation) -> dict:
        b = self.cfg.gaussmi
        dev = view.device
        logodds = view.column(self.COLUMN)
        self.visited = (self.visited + [(np.asarray(obs.T_wc[:3, 3], float), yaw_of_camera(obs.T_wc))])[-GAUSSMI_KEPT_VIEWS:]
        if len(view) == 0:
            return {}
        sp = view.splats()
        T = float_tensor(obs.T_wc, dev)
        view = capture_view(view, obs)
        out = view.output
        L = gaussmi_loss_image(out.features[0], out.depth[0] * out.alpha[0], float_tensor(obs.rgb, dev),
                               float_tensor(obs.depth, dev)[..., None])
        S = view.splat_sums(gaussmi_evidence(L, b.lambda_L))
        touch = view.splat_sums(torch.ones_like(L)) >= GAUSSMI_MIN_WEIGHT
        c = direction_weights(sp["means"], T[None, :3, 3])[0]
        logodds[:] = gaussmi_logodds_update(logodds, c, S, touch, b.lambda_T)
        return {"updated": int(touch.sum()), "negative_share": float((logodds < 0).any(-1).float().mean())}

    @torch.no_grad()
    def view_scores(self, view: MapView, poses: np.ndarray) -> torch.Tensor:
        """sum_p sum_i w_i(p) g_i per candidate (before the revisit discount)."""
        dev = view.device
        if len(view) == 0:
            return torch.zeros(len(poses), dtype=torch.float64)
        sp = view.splats()
        logodds = view.column(self.COLUMN)
        scores = torch.zeros(len(poses), dtype=torch.float64)
        gain = lambda Tc: gaussmi_gain(logodds, direction_weights(sp["means"], Tc[:, :3, 3]))[..., None]  # noqa: E731
        for cams, out in render_candidates(sp, gain, float_tensor(poses, dev), self.K_score.to(dev), self.width,
                                           self.height, near=view.near, far=view.far,
                                           backend=self.cfg.mapper.backend):
            scores[cams] = out.features[..., 0].double().sum(dim=(1, 2)).cpu()
        return scores

    def score(self, view: MapView, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        raw = self.view_scores(view, poses).numpy()
        disc = np.array([revisit_discount(T[:3, 3], yaw_of_camera(T), self.visited) for T in poses])
        return raw * (1.0 - disc)

    def get_state(self) -> dict:
        return {"visited_positions": np.array([p for p, _ in self.visited]).reshape(-1, 3),
                "visited_yaws": [y for _, y in self.visited]}

    def set_state(self, state: dict) -> None:
        self.visited = [(np.asarray(p, float), float(y))
                        for p, y in zip(state["visited_positions"], state["visited_yaws"])]

# ---------------------------------------------------------------------------------- FisherRF
def fisher_scores(H_cams: FisherDiag, H_train: FisherDiag, lam: float) -> torch.Tensor:
    """[C] sum over parameters of H_cand / (H_train + lambda), H_cams per camera ([C,N,...])."""
    return sum((hc.double() / (ht.double() + lam)).flatten(1).sum(1) for hc, ht in zip(H_cams, H_train))


class FisherRFSelector(_Scoring):
    """FisherRF (Jiang et al., ECCV 2024): expected information from the diagonal Hessian."""

    name = "fisherrf"
    section, settings = "fisherrf", FisherRFConfig
    CHUNK_BYTES = 256 << 20  # per Hessian call: the kernel's [C,N,66] buffer plus the pairs' G and J

    def __init__(self, cfg: ScenarioConfig) -> None:
        super().__init__(cfg)
        self.train_poses: list[np.ndarray] = []

    def observe(self, view: MapView, obs: Observation) -> dict:
        self.train_poses.append(np.asarray(obs.T_wc, np.float32))
        return {}

    def _chunks(self, view: MapView, poses: np.ndarray, reduce: bool):
        """Diagonal Hessians of the views T_wc [V,4,4], a chunk of cameras per kernel call (sized so
        a call stays within CHUNK_BYTES, about 1 KB per camera and splat)."""
        sp = view.splats()
        step = int(min(64, max(1, self.CHUNK_BYTES // (1024 * max(1, len(view))))))
        K = self.K_score.to(view.device)
        for s in range(0, len(poses), step):
            vm = torch.linalg.inv(float_tensor(poses[s:s + step], view.device))
            yield render_fisher_diag(sp["means"], sp["quats"], sp["log_scales"], sp["opacity_logits"],
                                     sp["colors"], vm, K[None].expand(vm.shape[0], 3, 3).contiguous(),
                                     self.width, self.height, view.near, view.far, reduce=reduce)

    def hessian(self, view: MapView, poses: np.ndarray) -> FisherDiag:
        """Diagonal Hessian (position, color, scale, opacity) summed over the views T_wc [V,4,4]."""
        parts = list(self._chunks(view, poses, reduce=True))
        return FisherDiag(*(sum(fields) for fields in zip(*parts)))

    @torch.no_grad()
    def score(self, view: MapView, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        if len(view) == 0 or not self.train_poses:
            return np.zeros(len(poses))
        H_train = self.hessian(view, np.stack(self.train_poses))
        lam = self.cfg.fisherrf.regularizer
        scores = [fisher_scores(h, H_train, lam) for h in self._chunks(view, np.asarray(poses), reduce=False)]
        return torch.cat(scores).cpu().numpy()

    def get_state(self) -> dict:
        return {"train_poses": np.array(self.train_poses, np.float32).reshape(-1, 4, 4)}

    def set_state(self, state: dict) -> None:
        self.train_poses = list(np.asarray(state["train_poses"], np.float32))


# ---------------------------------------------------------------------------------- ActiveGS
def surfel_confidence(n_obs: torch.Tensor, v_sum: torch.Tensor, S: torch.Tensor) -> torch.Tensor:
    """conf = clamp(exp(1 - |v_bar|) S, 0, 1), v_bar the mean unit view direction (0 if unseen)."""
    v_bar = v_sum / n_obs.clamp_min(1)[:, None]
    return torch.where(n_obs > 0, (torch.exp(1 - v_bar.norm(dim=-1)) * S).clamp(0, 1), torch.zeros_like(S))


def occupancy_weight(distance: torch.Tensor) -> torch.Tensor:
    """ActiveGS's log-odds step 2.8 clip(1 - 0.1 d, 0, 1) of a voxel at distance d from the camera."""
    return 2.8 * (1 - 0.1 * distance).clamp(0, 1)


class VoxelMap:
    """ActiveGS's voxel map over its scene's bounding box (mapping/voxel_map.py of its code): voxel
    centers on a grid of `voxel` (the box split into whole voxels, each axis its own size), log-odds in
    [-4.5, 4.5], occupied at P >= 0.8, free at P <= 0.2, unexplored until a depth frame's frustum
    reached the voxel. Visibility is by projecting voxel centers, as there: a center is seen when it
    projects into the image in front of the camera and nearer than the depth at its pixel."""

    OCC = math.log(0.8 / 0.2)
    FREE = math.log(0.2 / 0.8)

    def __init__(self, lo: np.ndarray, hi: np.ndarray, voxel: float) -> None:
        self.lo = np.asarray(lo, float)
        extent = np.asarray(hi, float) - self.lo
        self.dims = np.maximum(1, np.ceil(extent / voxel - 1e-9).astype(int))
        self.size = extent / self.dims
        ijk = np.stack(np.meshgrid(*[np.arange(d) for d in self.dims], indexing="ij"), -1).reshape(-1, 3)
        self.centers = torch.as_tensor(self.lo + (ijk + 0.5) * self.size)
        self.logodds = torch.zeros(len(self.centers), dtype=torch.float64)
        self.unexplored = torch.ones(len(self.centers), dtype=torch.bool)

    @property
    def size_total(self) -> int:
        """All voxels of the map: the denominator of the exploration utility."""
        return len(self.centers)

    def index(self, points: torch.Tensor) -> torch.Tensor:
        """Flat voxel index of world points [...,3]; -1 outside the box."""
        ijk = torch.floor((points.double() - torch.as_tensor(self.lo)) / torch.as_tensor(self.size)).long()
        dims = torch.as_tensor(self.dims)
        inside = ((ijk >= 0) & (ijk < dims)).all(-1)
        flat = (ijk[..., 0] * dims[1] + ijk[..., 1]) * dims[2] + ijk[..., 2]
        return torch.where(inside, flat, torch.full_like(flat, -1))

    @staticmethod
    def seen_in_front(centers: torch.Tensor, T_wc: torch.Tensor, K: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        """[C,M] bool: voxel centers [M,3] that project into camera c's image (T_wc [C,4,4], K [3,3],
        depth [C,H,W] in meters) in front of it and nearer than the depth at their pixel."""
        H, W = depth.shape[-2:]
        R, t = T_wc[:, :3, :3], T_wc[:, :3, 3]
        cam = torch.einsum("cji,cmj->cmi", R, centers[None] - t[:, None])  # R^T (x - t)
        z = cam[..., 2]
        zs = torch.where(z > 0, z, torch.ones_like(z))
        u = torch.floor(K[0, 0] * cam[..., 0] / zs + K[0, 2]).long()
        v = torch.floor(K[1, 1] * cam[..., 1] / zs + K[1, 2]).long()
        inside = (z > 0) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
        flat = torch.where(inside, v * W + u, torch.zeros_like(u))
        d = torch.gather(depth.reshape(len(T_wc), -1), 1, flat)
        return inside & (d > z)

    def integrate(self, depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray) -> None:
        """One depth frame (0 = no return, taken as the range's far end): voxels holding a measured
        point +w, other voxels in the frustum before the measured depth -w, w = occupancy_weight."""
        D = torch.as_tensor(np.asarray(depth, float))
        T = torch.as_tensor(np.asarray(T_wc, float))
        H, W = D.shape
        rays = torch.as_tensor(pixel_rays(W, H, np.asarray(K, float)))
        valid = D > 0
        points = T[:3, 3] + (rays[valid] * D[valid][:, None]) @ T[:3, :3].T
        hit_idx = self.index(points)
        hit = torch.zeros_like(self.unexplored)
        hit[hit_idx[hit_idx >= 0]] = True
        passed = self.seen_in_front(self.centers, T[None], torch.as_tensor(np.asarray(K, float)),
                                    torch.where(valid, D, torch.full_like(D, EXPLORE_RANGE))[None])[0] & ~hit
        w = occupancy_weight((self.centers - T[:3, 3]).norm(dim=-1))
        self.logodds = (self.logodds + torch.where(hit, w, 0.0) - torch.where(passed, w, 0.0)).clamp(-4.5, 4.5)
        self.unexplored &= ~(hit | passed)

    def visible_unexplored(self, T_wc: np.ndarray, K: np.ndarray, depth: torch.Tensor) -> np.ndarray:
        """Unexplored voxels [C] seen from cameras T_wc [C,4,4] whose rendered depth [C,H,W] is given:
        no surface (depth < 0.001) reads as far, every depth clamped to the range [near 0.001, 5 m]."""
        d = torch.where(depth < 0.001, torch.full_like(depth, 1e4), depth).clamp(0.001, EXPLORE_RANGE).double()
        todo = self.centers[self.unexplored]
        if len(todo) == 0:
            return np.zeros(len(T_wc))
        seen = self.seen_in_front(todo, torch.as_tensor(np.asarray(T_wc, float)), torch.as_tensor(np.asarray(K, float)), d)
        return seen.sum(1).double().numpy()

    @property
    def free(self) -> torch.Tensor:
        return self.logodds <= self.FREE

    @property
    def occupied(self) -> torch.Tensor:
        return self.logodds >= self.OCC


def activegs_combine(utility: np.ndarray, lengths: np.ndarray, path_weight: float,
                     rng: np.random.Generator | None = None) -> np.ndarray:
    """U / sum U - path_weight * L / sum L; when every utility is 0, random scores (its
    cal_view_scores); a zero length sum leaves the path term out."""
    if not utility.sum() > 0:
        return (rng or np.random.default_rng(0)).random(len(utility))
    p = lengths / lengths.sum() if lengths.sum() > 0 else np.zeros_like(lengths)
    return utility / utility.sum() - path_weight * p


class ActiveGSSelector(_Scoring):
    """ActiveGS (Jin et al., RA-L 2025): exploration and surfel-confidence utility, path term."""

    name = "activegs"
    section, settings = "activegs", ActiveGSConfig
    SEEN_WEIGHT = 0.03
    columns = {"ags_nobs": (), "ags_vsum": (3,), "ags_S": ()}  # surfel observations, view-direction sum, S

    def __init__(self, cfg: ScenarioConfig) -> None:
        c = cfg.camera
        super().__init__(cfg, max(1, c.width // 4), max(1, c.height // 4))  # ActiveGS: quarter resolution
        self.voxels: VoxelMap | None = None
        self.bounds: np.ndarray | None = None  # the scene's box (2,3), set by the loop (`attach_scene`)
        self.last_center: np.ndarray | None = None
        self.rng = np.random.default_rng([cfg.seed, 7919])

    def attach_scene(self, bounds: np.ndarray) -> None:
        """The scene's bounding box (2,3): ActiveGS's voxel map spans its scene."""
        self.bounds = np.asarray(bounds, float)

    def confidence(self, view: MapView) -> torch.Tensor:
        return surfel_confidence(view.column("ags_nobs"), view.column("ags_vsum"), view.column("ags_S"))

    def observe_space(self, depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray) -> None:
        """Integrate one depth frame into the voxel map (made on the first frame: over the scene's box,
        or, for a selector driven without a scene, `activegs.extent` around the camera)."""
        b = self.cfg.activegs
        if self.voxels is None:
            if self.bounds is None:
                half = 0.5 * np.asarray(b.extent, float)
                self.bounds = np.stack([T_wc[:3, 3] - half, T_wc[:3, 3] + half])
            self.voxels = VoxelMap(self.bounds[0], self.bounds[1], b.voxel)
        self.voxels.integrate(depth, K, T_wc)
        self.last_center = np.asarray(T_wc[:3, 3], float)

    def observe(self, view: MapView, obs: Observation) -> dict:
        self.observe_space(obs.depth, obs.K, obs.T_wc)
        n_obs, v_sum, S = view.column("ags_nobs"), view.column("ags_vsum"), view.column("ags_S")
        if len(view) == 0:
            return {}
        dev = view.device
        sp = view.splats()
        T = float_tensor(obs.T_wc, dev)
        H, W = obs.depth.shape
        weight = capture_view(view, obs).splat_sums(torch.ones(H, W, device=dev))
        to_cam = T[:3, 3][None] - sp["means"]
        dist = to_cam.norm(dim=-1)
        v = to_cam / dist.clamp_min(1e-9)[:, None]
        n_dot_v = observation_weights(sp["means"], splat_normals(sp["quats"]), T[None, :3, 3])[0]
        seen = (weight > self.SEEN_WEIGHT) & (n_dot_v > 0)
        n_obs[seen] += 1
        v_sum[seen] += v[seen]
        S[seen] += (1 - (dist[seen] / EXPLORE_RANGE).clamp(0, 1)) * n_dot_v[seen].clamp(0, 1)
        return {"seen": int(seen.sum())}

    def utilities(self, view: MapView, poses: np.ndarray) -> np.ndarray:
        """U = w U_explore + U_exploit per candidate (before normalization and path term), w =
        `activegs.explore_weight` (its code: 1000)."""
        explore, exploit = self.explore_exploit(view, poses)
        return self.cfg.activegs.explore_weight * explore + exploit

    @torch.no_grad()
    def explore_exploit(self, view: MapView, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(U_explore [C], U_exploit [C]) per candidate, from one render per candidate at quarter
        resolution (its planning/confidence.py)."""
        K = self.K_score.numpy().astype(float)
        explore, exploit = np.zeros(len(poses)), np.zeros(len(poses))
        R = EXPLORE_RANGE
        for cams, D, C in self._renders(view, poses):
            if self.voxels is not None:
                explore[cams] = self.voxels.visible_unexplored(poses[cams], K, D) / self.voxels.size_total
            C = torch.where(D > R, torch.ones_like(D), C)
            D_surface = torch.where(D < 0.001, torch.full_like(D, 0.5 * R), D)
            exploit[cams] = ((1 - C) * D_surface / R).mean(dim=(1, 2)).double().numpy()
        return explore, exploit

    def _renders(self, view: MapView, poses: np.ndarray):
        """(cameras, depth [c,H,W], confidence [c,H,W]) of the map at the candidates, on the CPU; an
        empty map renders no surface anywhere."""
        if len(view) == 0:
            zeros = torch.zeros(len(poses), self.height, self.width)
            yield slice(0, len(poses)), zeros, zeros
            return
        dev = view.device
        for cams, out in render_candidates(view.splats(), self.confidence(view)[:, None], float_tensor(poses, dev),
                                           self.K_score.to(dev), self.width, self.height, near=view.near,
                                           far=view.far, outputs=("features", "depth"),
                                           backend=self.cfg.mapper.backend):
            yield cams, out.depth[..., 0].cpu(), out.features[..., 0].cpu()

    def path_lengths(self, poses: np.ndarray, lengths: np.ndarray | None) -> np.ndarray:
        """The planned lengths [C], or where the loop passed none, the straight line from the last view."""
        if lengths is None:
            ref = self.last_center if self.last_center is not None else np.zeros(3)
            lengths = np.linalg.norm(np.asarray(poses)[:, :3, 3] - ref, axis=-1)
        return np.asarray(lengths, float)

    def score(self, view: MapView, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        return activegs_combine(self.utilities(view, poses), self.path_lengths(poses, lengths),
                                self.cfg.activegs.path_weight, self.rng)

    def get_state(self) -> dict:
        state = {"rng": self.rng.bit_generator.state, "bounds": self.bounds, "last_center": self.last_center}
        if self.voxels is not None:
            state["voxels"] = {"logodds": self.voxels.logodds, "unexplored": self.voxels.unexplored}
        return state

    def set_state(self, state: dict) -> None:
        self.rng.bit_generator.state = state["rng"]
        self.bounds = None if state["bounds"] is None else np.asarray(state["bounds"], float)
        self.last_center = None if state["last_center"] is None else np.asarray(state["last_center"], float)
        if "voxels" in state:
            self.voxels = VoxelMap(self.bounds[0], self.bounds[1], self.cfg.activegs.voxel)
            self.voxels.logodds = torch.as_tensor(state["voxels"]["logodds"], dtype=torch.float64).clone()
            self.voxels.unexplored = torch.as_tensor(state["voxels"]["unexplored"], dtype=torch.bool).clone()
