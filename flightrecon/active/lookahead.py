"""`gaussmi2d_lookahead`: gaussmi2d_explore's information, valued over short sequences of views per
second of flight (beyond the paper; docs/equations.md, "Looking further than one view").

The one-view score is greedy: it flies to the best view now even when a slightly worse one opens
the way to a much better second view, and it pays no attention to how long a view takes to reach.
This selector keeps gaussmi2d_explore's information, in the same units for the seen and the unseen,
but splits each candidate's score into the items it is made of: per splat, the paper's gain f_n^[i]
summed over the pixels the splat reaches (Eq. 22 before the sum over splats), and per cell of
unknown space, the prior gain of the frontier rays that enter it. A sequence of views gains, per
item, the most any of its views gains there (a second look at the same splat or the same unseen
cell adds nothing beyond the better look), so the value of one view is exactly gaussmi2d_explore's
score. The `lookahead.beam` best candidates by one-view rate are searched exhaustively for the
sequence of up to `lookahead.depth` views with the highest information per second:

    U(S) = G(S) / (|S| view_time + travel(S))

with travel the rest-to-rest, jerk-limited time of each leg (planning.timing, the planner's limits):
the first over the planned path's length, the others straight between the candidates (not checked
for collisions: the loop plans again at every step). A candidate scores the best U of the sequences
it begins; the loop flies to the first view of the best sequence and plans afresh there.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import torch

from flightrecon.active.explore import PRIOR_GAIN, GaussMI2DExplore
from flightrecon.active.gaussmi2d import depth_noise_prior, information_gain
from flightrecon.active.protocol import MapView, Observation
from flightrecon.active.reliability import observation_weights, splat_normals
from flightrecon.config import ScenarioConfig, option
from flightrecon.planning.feasibility import PlanningSettings
from flightrecon.planning.library import wrap_angle
from flightrecon.planning.timing import Limits, time_path
from flightrecon.render import render


@dataclass(frozen=True)
class LookaheadConfig:
    """`[lookahead]`: how far gaussmi2d_lookahead looks (its information reads `[explore]` and `[reliability]`)."""

    depth: int = option(2, 1, 3, doc="views per sequence searched (1: gaussmi2d_explore's choice per second)")
    beam: int = option(8, 1, 32, doc="best candidates by one-view rate whose sequences are searched")
    view_time: float = option(2.0, 0.01, 1e6, doc="seconds a view costs besides its flight (capture, settling, "
                              "mapping while hovering); large: information per view, travel time ignored")
    cell: float = option(0.3, 0.05, 5.0, doc="unknown space is shared between views per cell of this size (m)")


def camera_yaw(T_wc: np.ndarray) -> np.ndarray:
    """Heading (rad) of camera poses [...,4,4]: the optical axis's direction in the horizontal plane."""
    T = np.asarray(T_wc, float)
    return np.arctan2(T[..., 1, 2], T[..., 0, 2])


def leg_time(distance: float, turn: float, limits: Limits) -> float:
    """Seconds of a rest-to-rest, jerk-limited move over `distance` m turning by `turn` rad."""
    traj = time_path(np.array([[0.0, 0.0, 0.0], [float(distance), 0.0, 0.0]]), np.array([0.0, float(turn)]), limits)
    return math.inf if traj is None else traj.duration


def sequence_rates(items: np.ndarray, first_time: np.ndarray, between_time: np.ndarray, view_time: float,
                   depth: int) -> tuple[np.ndarray, list[tuple[int, ...]]]:
    """Per candidate a of items [M,I] (information >= 0 per item): the best rate
    max_S G(S) / (|S| view_time + travel(S)) over sequences S of distinct candidates, at most `depth`
    long, that begin with a, and that sequence. G(S) = sum over items of the largest value among S;
    travel(S) = first_time[S_0] + sum of between_time[S_k, S_k+1]."""
    M = items.shape[0]
    best = np.full(M, -np.inf)
    plans: list[tuple[int, ...]] = [(a,) for a in range(M)]
    for n in range(1, min(depth, M) + 1):
        for seq in itertools.permutations(range(M), n):
            gain = items[list(seq)].max(axis=0).sum()
            time = n * view_time + first_time[seq[0]] + sum(between_time[i, j] for i, j in zip(seq, seq[1:]))
            rate = gain / time
            if rate > best[seq[0]]:
                best[seq[0]], plans[seq[0]] = rate, seq
    return best, plans


class GaussMI2DLookahead(GaussMI2DExplore):
    """gaussmi2d_explore's information over short sequences of views, per second (module docstring)."""

    name = "gaussmi2d_lookahead"
    section, settings = "lookahead", LookaheadConfig

    def __init__(self, cfg: ScenarioConfig) -> None:
        super().__init__(cfg)
        self.limits = PlanningSettings.from_config(cfg).limits
        self.here: np.ndarray | None = None  # the camera pose of the last captured frame: where the drone is

    def observe(self, view: MapView, obs: Observation) -> dict:
        self.here = np.asarray(obs.T_wc, float)
        return super().observe(view, obs)

    def splat_items(self, view: MapView, poses: np.ndarray) -> torch.Tensor:
        """Per camera T_wc [M,4,4] and splat: f_n^[i] sum_j P(z_j) T^[i,j], the splat's share of the
        candidate's MI (Eq. 22 before the sum over splats), float64 [M,N]. One render of all M cameras
        with per-camera features; the per-splat pixel sums are the gradient of the image sums
        (render.rendered_view's identity)."""
        s, r = self.cfg.selector, self.cfg.reliability
        splats = view.splats()
        T = torch.as_tensor(np.asarray(poses, np.float32), device=view.device)
        w = observation_weights(splats["means"], splat_normals(splats["quats"]), T[:, :3, 3])
        gain = information_gain(self.reliability(view), w, r.w_min, self.weighted)  # [M,N]
        leaf = gain[..., None].detach().clone().requires_grad_(True)
        K = self.K_score.to(view.device)[None].expand(len(poses), 3, 3).contiguous()
        with torch.enable_grad():
            one = r.measurement_prior == "one"
            out = render(splats["means"], splats["quats"], splats["log_scales"], splats["opacity_logits"], leaf,
                         torch.linalg.inv(T), K, s.scoring_width, s.scoring_height, near=view.near, far=view.far,
                         outputs=("features",) if one else ("features", "depth"), backend=self.cfg.mapper.backend)
            image = out.features if one else out.features * depth_noise_prior(out.depth).detach()
            (sums,) = torch.autograd.grad(image.sum(), leaf)
        return (gain.double() * sums[..., 0].double()).cpu()

    def frontier_items(self, entries: np.ndarray) -> np.ndarray:
        """Per camera of `frontier_entries` [M,R,3]: the frontier gain of its counted rays, binned by the
        `lookahead.cell` where each ray enters unknown space, float64 [M, cells] (cells any of them reaches)."""
        counted = np.isfinite(entries[..., 0])
        cam = np.nonzero(counted)[0]
        cells = np.floor(entries[counted] / self.cfg.lookahead.cell).astype(np.int64)
        _, cell = np.unique(cells, axis=0, return_inverse=True)
        out = np.zeros((len(entries), int(cell.max()) + 1 if len(cell) else 0))
        np.add.at(out, (cam, cell.reshape(-1)), PRIOR_GAIN * self.cfg.explore.stride ** 2)
        return out

    def first_leg_times(self, poses: np.ndarray, lengths: np.ndarray | None) -> np.ndarray:
        """Seconds to each camera T_wc [C,4,4] from where the drone is: over the planned `lengths`
        [C] m, or straight when they are unknown."""
        here = poses[0] if self.here is None else self.here
        dist = np.linalg.norm(poses[:, :3, 3] - here[:3, 3], axis=1) if lengths is None else np.asarray(lengths, float)
        turn = wrap_angle(camera_yaw(poses) - camera_yaw(here))
        return np.array([leg_time(d, t, self.limits) for d, t in zip(dist, turn)])

    def between_times(self, poses: np.ndarray) -> np.ndarray:
        """Seconds [M,M] from each camera T_wc [M,4,4] to each other, straight."""
        pos, yaw = poses[:, :3, 3], camera_yaw(poses)
        between = np.zeros((len(poses), len(poses)))
        for i, j in itertools.permutations(range(len(poses)), 2):
            between[i, j] = leg_time(np.linalg.norm(pos[j] - pos[i]), wrap_angle(yaw[j] - yaw[i]), self.limits)
        return between

    def score(self, view: MapView, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        poses = np.asarray(poses, float)
        la = self.cfg.lookahead
        first = self.first_leg_times(poses, lengths)
        entries = self.frontier_entries(poses)  # marched once: the one-view scores and the beam's items
        offset = torch.as_tensor(self.frontier_gain(poses, entries), dtype=torch.float64)
        # per second; lower bounds where the MI's cut left one
        one_view = self.mutual_information(view, poses, offset).numpy() / (la.view_time + first)
        if la.depth == 1 or len(poses) < 2:
            return one_view
        top = np.argsort(-one_view, kind="stable")[:la.beam]
        items = np.concatenate([self.splat_items(view, poses[top]).numpy() if len(view) else np.zeros((len(top), 0)),
                                self.frontier_items(entries[top])], axis=1)
        scores = one_view.copy()
        scores[top], _ = sequence_rates(items, first[top], self.between_times(poses[top]), la.view_time, la.depth)
        return scores

    def get_state(self) -> dict:
        state = super().get_state()
        if self.here is not None:
            state["here"] = self.here
        return state

    def set_state(self, state: dict) -> None:
        self.here = np.asarray(state["here"]) if "here" in state else None
        super().set_state({k: v for k, v in state.items() if k != "here"})
