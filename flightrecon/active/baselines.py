"""The paper's baselines as view selectors (their papers and public code; docs/architecture.md, "Selectors").

All of them share our online 2DGS mapper, our planner and our candidate library (the loop hands
every selector the same feasible candidates), so a comparison isolates the selection criterion.
Per-splat state lives in columns each selector adds to the GaussianMap (`protocol.ensure_column`),
so it stays aligned with the splats through growth and pruning. None of them keeps 2D reliability,
so `reliable_share` is 0 and the stopping rule never stops them.

- `gaussmi` (Xie and Pan, RSS 2025): four world-horizontal reliability log-odds per splat
  [+x, +y, -x, -y], updated from its loss image L = 0.95 |I - I_obs| + 0.05 |D_acc - D_obs|; view
  score = sum_p sum_i w_i(p) g_i with g_i = sum_k c_ik (-ln P_ik), times (1 - revisit discount).
  docs/baselines.md lists what follows its public code and the one departure (no transmittance
  gate in the evidence sum, which our rasterizer does not expose per splat and pixel).
- `fisherrf` (Jiang et al., ECCV 2024): score = sum_theta H_cand / (H_train + lambda) with the
  rasterizer's squared-contribution diagonal Hessian (position, color, scale, opacity); H_train
  sums over all frames collected so far and is recomputed at each selection (one view is chosen
  per step, so greedy batch acquisition reduces to the argmax). Both at the scoring resolution.
- `activegs` (Jin et al., RA-L 2025): surfel confidence, a 0.2 m occupancy voxel map and its
  exploration utility, the confidence-weighted exploitation utility, and the path-length term.
  Its own pitch-free candidate generator (regions of interest + random) is replaced by our
  planner's library (a quadrotor with a fixed camera cannot fly pitch); the path length is the
  planned trajectory's length when the loop passes it (`lengths=`), else the straight-line distance
  from the last captured camera, and "all voxels" is the fixed grid `baselines.activegs_extent`
  centered on the first camera. A splat counts as seen in a view when its total blend weight over
  the image exceeds 0.03 and it faces the camera.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from flightrecon.active.candidate_views import render_candidates
from flightrecon.active.protocol import Observation, capture_view, ensure_column, float_tensor, scoring_intrinsics
from flightrecon.active.reliability import observation_weights, splat_normals
from flightrecon.config import ScenarioConfig
from flightrecon.geometry import pixel_rays, yaw_of_camera
from flightrecon.mapping.mapper import OnlineMapper
from flightrecon.render import FisherDiag, load_extension, render_fisher_diag

EXPLORE_RANGE = 5.0  # m, ActiveGS's utility range
# GauSS-MI's constants (its public configs and code, docs/baselines.md)
GAUSSMI_RGB_WEIGHT = 0.95  # loss_rgb_alpha
GAUSSMI_MIN_LOSS = 1e-4  # reli_min_loss
GAUSSMI_CLAMP = 10.0  # log-odds clip of input_logodds
GAUSSMI_MIN_WEIGHT = 1.0  # our stand-in for reli_touch_threshold (5 pixels with transmittance > 0.8)
GAUSSMI_DISCOUNT = 0.95  # pre_discount_coeff
GAUSSMI_FREE_VIEWS = 5  # no revisit discount while at most this many viewpoints were taken
GAUSSMI_KEPT_VIEWS = 100  # max_num_previous_vps


class _Scoring:
    """Shared: the scoring intrinsics of the config's camera at the selector's scoring resolution."""

    def __init__(self, cfg: ScenarioConfig, width: int | None = None, height: int | None = None) -> None:
        self.width, self.height = width or cfg.selector.scoring_width, height or cfg.selector.scoring_height
        self.K_score = scoring_intrinsics(cfg, self.width, self.height)

    def reliable_share(self, mapper: OnlineMapper) -> float:
        return 0.0


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
    name = "gaussmi"
    COLUMN = "gaussmi_logodds"

    def __init__(self, cfg: ScenarioConfig) -> None:
        super().__init__(cfg)
        self.cfg = cfg
        self.visited: list[tuple[np.ndarray, float]] = []

    @torch.no_grad()
    def observe(self, mapper: OnlineMapper, obs: Observation) -> dict:
        b = self.cfg.baselines
        dev = mapper.device
        logodds = ensure_column(mapper, self.COLUMN, (4,))
        self.visited = (self.visited + [(np.asarray(obs.T_wc[:3, 3], float), yaw_of_camera(obs.T_wc))])[-GAUSSMI_KEPT_VIEWS:]
        if len(mapper.map) == 0:
            return {}
        sp = mapper.splats()
        T = float_tensor(obs.T_wc, dev)
        view = capture_view(mapper, obs)
        out = view.output
        L = gaussmi_loss_image(out.features[0], out.depth[0] * out.alpha[0], float_tensor(obs.rgb, dev),
                               float_tensor(obs.depth, dev)[..., None])
        S = view.splat_sums(gaussmi_evidence(L, b.gaussmi_lambda_L))
        touch = view.splat_sums(torch.ones_like(L)) >= GAUSSMI_MIN_WEIGHT
        c = direction_weights(sp["means"], T[None, :3, 3])[0]
        logodds[:] = gaussmi_logodds_update(logodds, c, S, touch, b.gaussmi_lambda_T)
        return {"updated": int(touch.sum()), "negative_share": float((logodds < 0).any(-1).float().mean())}

    @torch.no_grad()
    def view_scores(self, mapper: OnlineMapper, poses: np.ndarray) -> torch.Tensor:
        """sum_p sum_i w_i(p) g_i per candidate (before the revisit discount)."""
        dev = mapper.device
        if len(mapper.map) == 0:
            return torch.zeros(len(poses), dtype=torch.float64)
        sp = mapper.splats()
        logodds = ensure_column(mapper, self.COLUMN, (4,))
        scores = torch.zeros(len(poses), dtype=torch.float64)
        gain = lambda Tc: gaussmi_gain(logodds, direction_weights(sp["means"], Tc[:, :3, 3]))[..., None]  # noqa: E731
        for cams, out in render_candidates(sp, gain, float_tensor(poses, dev), self.K_score.to(dev), self.width,
                                           self.height, near=mapper.near, far=mapper.far,
                                           backend=self.cfg.mapper.backend):
            scores[cams] = out.features[..., 0].double().sum(dim=(1, 2)).cpu()
        return scores

    def score(self, mapper: OnlineMapper, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        raw = self.view_scores(mapper, poses).numpy()
        disc = np.array([revisit_discount(T[:3, 3], yaw_of_camera(T), self.visited) for T in poses])
        return raw * (1.0 - disc)

# ---------------------------------------------------------------------------------- FisherRF
def fisher_scores(H_cams: FisherDiag, H_train: FisherDiag, lam: float) -> torch.Tensor:
    """[C] sum over parameters of H_cand / (H_train + lambda), H_cams per camera ([C,N,...])."""
    return sum((hc.double() / (ht.double() + lam)).flatten(1).sum(1) for hc, ht in zip(H_cams, H_train))


class FisherRFSelector(_Scoring):
    name = "fisherrf"
    CHUNK_BYTES = 256 << 20  # per Hessian call: the kernel's [C,N,66] buffer plus the pairs' G and J

    def __init__(self, cfg: ScenarioConfig) -> None:
        super().__init__(cfg)
        self.cfg = cfg
        self.train_poses: list[np.ndarray] = []

    def observe(self, mapper: OnlineMapper, obs: Observation) -> dict:
        self.train_poses.append(np.asarray(obs.T_wc, np.float32))
        return {}

    def _chunks(self, mapper: OnlineMapper, poses: np.ndarray, reduce: bool):
        """Diagonal Hessians of the views T_wc [V,4,4], a chunk of cameras per kernel call (sized so
        a call stays within CHUNK_BYTES, about 1 KB per camera and splat)."""
        sp = mapper.splats()
        step = int(min(64, max(1, self.CHUNK_BYTES // (1024 * max(1, len(mapper.map))))))
        K = self.K_score.to(mapper.device)
        for s in range(0, len(poses), step):
            vm = torch.linalg.inv(float_tensor(poses[s:s + step], mapper.device))
            yield render_fisher_diag(sp["means"], sp["quats"], sp["log_scales"], sp["opacity_logits"],
                                     sp["colors"], vm, K[None].expand(vm.shape[0], 3, 3).contiguous(),
                                     self.width, self.height, mapper.near, mapper.far, reduce=reduce)

    def hessian(self, mapper: OnlineMapper, poses: np.ndarray) -> FisherDiag:
        """Diagonal Hessian (position, color, scale, opacity) summed over the views T_wc [V,4,4]."""
        parts = list(self._chunks(mapper, poses, reduce=True))
        return FisherDiag(*(sum(fields) for fields in zip(*parts)))

    @torch.no_grad()
    def score(self, mapper: OnlineMapper, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        if len(mapper.map) == 0 or not self.train_poses:
            return np.zeros(len(poses))
        H_train = self.hessian(mapper, np.stack(self.train_poses))
        lam = self.cfg.baselines.fisherrf_lambda
        scores = [fisher_scores(h, H_train, lam) for h in self._chunks(mapper, np.asarray(poses), reduce=False)]
        return torch.cat(scores).cpu().numpy()


# ---------------------------------------------------------------------------------- ActiveGS
def surfel_confidence(n_obs: torch.Tensor, v_sum: torch.Tensor, S: torch.Tensor) -> torch.Tensor:
    """conf = clamp(exp(1 - |v_bar|) S, 0, 1), v_bar the mean unit view direction (0 if unseen)."""
    v_bar = v_sum / n_obs.clamp_min(1)[:, None]
    return torch.where(n_obs > 0, (torch.exp(1 - v_bar.norm(dim=-1)) * S).clamp(0, 1), torch.zeros_like(S))


def occupancy_weight(distance: torch.Tensor) -> torch.Tensor:
    """ActiveGS's log-odds step 2.8 clip(1 - 0.1 d, 0, 1) of a measurement at range d."""
    return 2.8 * (1 - 0.1 * distance).clamp(0, 1)


class VoxelMap:
    """ActiveGS's coarse occupancy grid: log-odds in [-4.5, 4.5], occupied at P >= 0.8, free at
    P <= 0.2, unexplored where no ray ever touched; a fixed box of `extent` around `center`."""

    OCC = math.log(0.8 / 0.2)

    def __init__(self, center: np.ndarray, extent: list, voxel: float) -> None:
        self.voxel = float(voxel)
        self.dims = np.maximum(1, np.ceil(np.asarray(extent, float) / voxel).astype(int))
        self.origin = np.asarray(center, float) - 0.5 * self.dims * voxel
        n = int(np.prod(self.dims))
        self.logodds = torch.zeros(n)
        self.touched = torch.zeros(n, dtype=torch.bool)

    def index(self, points: torch.Tensor) -> torch.Tensor:
        """Flat voxel index of world points [...,3]; -1 outside the grid."""
        ijk = torch.floor((points.double() - torch.as_tensor(self.origin)) / self.voxel).long()
        dims = torch.as_tensor(self.dims)
        inside = ((ijk >= 0) & (ijk < dims)).all(-1)
        flat = (ijk[..., 0] * dims[1] + ijk[..., 1]) * dims[2] + ijk[..., 2]
        return torch.where(inside, flat, torch.full_like(flat, -1))

    def integrate(self, depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray, stride: int = 4) -> None:
        """One depth frame (every `stride`-th pixel): +w at each ray's end voxel, -w along the ray."""
        rays = torch.as_tensor(pixel_rays(depth.shape[1], depth.shape[0], K)[::stride, ::stride].reshape(-1, 3))
        d = torch.as_tensor(np.asarray(depth, float)[::stride, ::stride].reshape(-1))
        ok = d > 0
        rays, d = rays[ok], d[ok]
        R, c = torch.as_tensor(T_wc[:3, :3]), torch.as_tensor(T_wc[:3, 3])
        dirs = rays @ R.T  # world, z-depth 1
        dist = d * dirs.norm(dim=-1)
        w = occupancy_weight(dist)
        end = self.index(c + dirs * d[:, None])
        steps = torch.arange(0.5, float(d.max()) / (self.voxel / 2) if len(d) else 0.5) * (self.voxel / 2)
        frac = steps[None, :] / dist[:, None].clamp_min(1e-9)  # along the ray, in units of its length
        free_pts = c + (dirs * d[:, None])[:, None, :] * frac[..., None]
        before = steps[None, :] < (dist[:, None] - self.voxel / 2)
        free = self.index(free_pts)
        wf = w[:, None].expand_as(free)
        m = before & (free >= 0)
        delta = torch.zeros_like(self.logodds, dtype=torch.float64)
        free_w = torch.zeros_like(delta).scatter_reduce(0, free[m], wf[m], "amax", include_self=True)
        occ_w = torch.zeros_like(delta).scatter_reduce(0, end[end >= 0], w[end >= 0], "amax", include_self=True)
        delta = torch.where(occ_w > 0, occ_w, -free_w)
        self.touched |= (occ_w > 0) | (free_w > 0)
        self.logodds = (self.logodds + delta.float()).clamp(-4.5, 4.5)

    def visible_unexplored(self, T_wc: np.ndarray, K: np.ndarray, width: int, height: int) -> np.ndarray:
        """Unexplored voxels seen from each camera T_wc [C,4,4]: along its pixel rays (at the given
        resolution, sampled every half voxel) up to 5 m, before the first occupied voxel. Returns
        counts [C]. The ray march is the extension's (csrc/voxel_rays.cpp)."""
        T = torch.as_tensor(np.asarray(T_wc, float))
        rays = torch.nn.functional.normalize(torch.as_tensor(pixel_rays(width, height, K).reshape(-1, 3)), dim=-1)
        dirs = torch.einsum("cij,rj->cri", T[:, :3, :3], rays)  # [C,R,3]
        return load_extension().count_unexplored(
            dirs.double(), T[:, :3, 3].double(), self.ray_samples().double(), torch.as_tensor(self.origin),
            torch.as_tensor(self.dims, dtype=torch.int64), self.voxel, self.logodds >= self.OCC,
            self.touched).numpy()

    def ray_samples(self) -> torch.Tensor:
        """Distances along a ray at which the utility samples the grid: every half voxel to 5 m."""
        return torch.arange(0.5, EXPLORE_RANGE / (self.voxel / 2)) * (self.voxel / 2)

    @property
    def size(self) -> int:
        return int(self.logodds.numel())


def activegs_combine(utility: np.ndarray, lengths: np.ndarray, path_weight: float) -> np.ndarray:
    """U / sum U - path_weight * L / sum L (a zero sum leaves its term out)."""
    u = utility / utility.sum() if utility.sum() > 0 else np.zeros_like(utility)
    p = lengths / lengths.sum() if lengths.sum() > 0 else np.zeros_like(lengths)
    return u - path_weight * p


class ActiveGSSelector(_Scoring):
    name = "activegs"
    SEEN_WEIGHT = 0.03

    def __init__(self, cfg: ScenarioConfig) -> None:
        c = cfg.camera
        super().__init__(cfg, max(1, c.width // 4), max(1, c.height // 4))  # ActiveGS: quarter resolution
        self.cfg = cfg
        self.voxels: VoxelMap | None = None
        self.last_center: np.ndarray | None = None

    def confidence(self, mapper: OnlineMapper) -> torch.Tensor:
        return surfel_confidence(ensure_column(mapper, "ags_nobs", ()), ensure_column(mapper, "ags_vsum", (3,)),
                                 ensure_column(mapper, "ags_S", ()))

    def observe_space(self, depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray) -> None:
        """Integrate one depth frame into the voxel map (the first frame places the grid)."""
        b = self.cfg.baselines
        if self.voxels is None:
            self.voxels = VoxelMap(T_wc[:3, 3], b.activegs_extent, b.activegs_voxel)
        self.voxels.integrate(depth, K, T_wc)
        self.last_center = np.asarray(T_wc[:3, 3], float)

    def observe(self, mapper: OnlineMapper, obs: Observation) -> dict:
        self.observe_space(obs.depth, obs.K, obs.T_wc)
        n_obs, v_sum, S = (ensure_column(mapper, "ags_nobs", ()), ensure_column(mapper, "ags_vsum", (3,)),
                           ensure_column(mapper, "ags_S", ()))
        if len(mapper.map) == 0:
            return {}
        dev = mapper.device
        sp = mapper.splats()
        T = float_tensor(obs.T_wc, dev)
        H, W = obs.depth.shape
        weight = capture_view(mapper, obs).splat_sums(torch.ones(H, W, device=dev))
        to_cam = T[:3, 3][None] - sp["means"]
        dist = to_cam.norm(dim=-1)
        v = to_cam / dist.clamp_min(1e-9)[:, None]
        n_dot_v = observation_weights(sp["means"], splat_normals(sp["quats"]), T[None, :3, 3])[0]
        seen = (weight > self.SEEN_WEIGHT) & (n_dot_v > 0)
        n_obs[seen] += 1
        v_sum[seen] += v[seen]
        S[seen] += (1 - (dist[seen] / EXPLORE_RANGE).clamp(0, 1)) * n_dot_v[seen].clamp(0, 1)
        return {"seen": int(seen.sum())}

    @torch.no_grad()
    def utilities(self, mapper: OnlineMapper, poses: np.ndarray) -> np.ndarray:
        """U = 1000 U_explore + U_exploit per candidate (before normalization and path term)."""
        K = self.K_score.numpy().astype(float)
        explore = np.zeros(len(poses))
        if self.voxels is not None:
            for s in range(0, len(poses), 16):
                explore[s:s + 16] = self.voxels.visible_unexplored(poses[s:s + 16], K, self.width, self.height)
            explore /= self.voxels.size
        exploit = np.zeros(len(poses))
        if len(mapper.map):
            dev = mapper.device
            sp = mapper.splats()
            conf = self.confidence(mapper)[:, None]
            for cams, out in render_candidates(sp, conf, float_tensor(poses, dev), self.K_score.to(dev), self.width,
                                               self.height, near=mapper.near, far=mapper.far,
                                               outputs=("features", "alpha", "depth"), backend=self.cfg.mapper.backend):
                D = out.depth[..., 0]
                surface = (out.alpha[..., 0] > 0.5) & (D <= EXPLORE_RANGE)
                C = torch.where(surface, out.features[..., 0].clamp(0, 1), torch.ones_like(D))
                exploit[cams] = ((1 - C) * D / EXPLORE_RANGE).mean(dim=(1, 2)).double().cpu().numpy()
        return 1000.0 * explore + exploit

    def score(self, mapper: OnlineMapper, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        if lengths is None:  # the loop did not pass planned lengths: straight line from the last view
            ref = self.last_center if self.last_center is not None else np.zeros(3)
            lengths = np.linalg.norm(np.asarray(poses)[:, :3, 3] - ref, axis=-1)
        return activegs_combine(self.utilities(mapper, poses), np.asarray(lengths, float),
                                self.cfg.baselines.activegs_path_weight)
