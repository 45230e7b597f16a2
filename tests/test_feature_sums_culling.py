"""The feature sums' culling (Morton groups and their blocks, SplatGroups in csrc/rasterize.h) held
to brute force: a call with one camera culls nothing and projects every splat in id order, so
scoring each camera alone must give the batch's sums bit for bit, at any thread count."""

import math

import numpy as np
import pytest
import torch

from flightrecon.geometry import camera_pose, intrinsics, rotmat_to_quat
from flightrecon.render import sided_feature_sums
from flightrecon.render.extension import load

W, H = 40, 30
NEAR, FAR = 0.05, 10.0


def _room(per_face: int = 1000, seed: int = 0) -> list[torch.Tensor]:
    """Splats on the six faces of the box [-2, 2] x [-2, 2] x [0, 3], facing in: more than one block
    of groups, and a camera inside sees some faces and culls the others."""
    g = torch.Generator().manual_seed(seed)
    lo, hi = torch.tensor([-2.0, -2.0, 0.0]), torch.tensor([2.0, 2.0, 3.0])
    means, quats = [], []
    for axis in range(3):
        for side, value in ((1.0, lo[axis]), (-1.0, hi[axis])):
            p = lo + torch.rand(per_face, 3, generator=g) * (hi - lo)
            p[:, axis] = value
            n = np.zeros(3)
            n[axis] = side
            t_u = np.roll(n, 1)
            R = np.stack([t_u, np.cross(n, t_u), n], axis=1)  # columns t_u, t_v, n
            means.append(p)
            quats.append(torch.tensor(rotmat_to_quat(R), dtype=torch.float32).expand(per_face, 4))
    n_all = 6 * per_face
    log_scales = torch.log(torch.rand(n_all, 2, generator=g) * 0.1 + 0.03)
    opac = torch.randn(n_all, generator=g) + 1.5
    return [torch.cat(means), torch.cat(quats), log_scales, opac]


def _straddler(splats: list[torch.Tensor], position: np.ndarray) -> list[torch.Tensor]:
    """The map plus a large splat whose center lies just behind the near plane of a camera at
    `position` looking along +x, facing it: it reaches across the near plane."""
    R = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # normal -x
    mean = torch.tensor(position + np.array([0.5 * NEAR, 0.0, 0.0]), dtype=torch.float32)
    extra = [mean[None], torch.tensor(rotmat_to_quat(R)[None], dtype=torch.float32),
             torch.full((1, 2), math.log(0.3)), torch.tensor([3.0])]
    return [torch.cat([a, b]) for a, b in zip(splats, extra)]


def _cameras(positions: list[np.ndarray], headings: int) -> tuple[torch.Tensor, torch.Tensor]:
    """viewmats and Ks of `headings` evenly spaced yaws at each position."""
    T = [camera_pose(p, 2 * math.pi * h / headings) for p in positions for h in range(headings)]
    vm = torch.linalg.inv(torch.tensor(np.stack(T), dtype=torch.float32))
    K = torch.tensor(intrinsics(W, H, 90.0), dtype=torch.float32).expand(len(T), 3, 3).contiguous()
    return vm, K


def _sums(splats, sided, vm, K, floor=0.0):
    out = sided_feature_sums(*splats, sided, vm, K, W, H, NEAR, FAR, w_min=0.1, floor=floor, backend="cpu")
    return torch.stack([out.sums, out.bound])


def _brute_force(splats, sided, vm, K, floor=0.0):
    """Each camera alone: nothing culled, every splat projected."""
    return torch.cat([_sums(splats, sided, vm[c:c + 1], K[c:c + 1], floor) for c in range(len(vm))], dim=1)


def _sided(n: int, seed: int = 1) -> torch.Tensor:
    return torch.rand(n, 2, generator=torch.Generator().manual_seed(seed)) * 2.0


INSIDE = [np.array([0.0, 0.0, 1.5]), np.array([1.2, -0.8, 1.0]), np.array([-1.7, 1.7, 2.8])]


@pytest.mark.parametrize("floor", [0.0, 0.3])
def test_batch_equals_brute_force_inside_the_map(floor):
    splats = _room()
    vm, K = _cameras(INSIDE, 6)
    sided = _sided(len(splats[0]))
    batch = _sums(splats, sided, vm, K, floor)
    assert (batch[0] > 0).all()
    assert torch.equal(batch, _brute_force(splats, sided, vm, K, floor))


def test_blocks_spare_the_tests_of_what_a_camera_cannot_see():
    splats = _room()
    vm, K = _cameras([np.array([6.0, 0.0, 1.5])], 1)  # outside the room, looking away from it (+x)
    _sums(splats, _sided(len(splats[0])), vm.expand(2, 4, 4).contiguous(), K.expand(2, 3, 3).contiguous())
    stats = load().last_stats()
    blocks = math.ceil(len(splats[0]) / (32 * 32))
    assert blocks > 1 and stats["tests"] == 2 * blocks and stats["projected"] == 0


def test_splat_across_the_near_plane():
    position = np.array([0.0, 0.0, 1.5])
    splats = _straddler(_room(), position)
    vm, K = _cameras([position], 4)  # the first looks along +x, at the straddler
    sided = _sided(len(splats[0]), seed=2)
    assert torch.equal(_sums(splats, sided, vm, K), _brute_force(splats, sided, vm, K))


def test_a_camera_that_sees_nothing():
    splats = _room()
    outside = np.array([6.0, 0.0, 1.5])  # outside the room, looking away from it (+x)
    vm, K = _cameras([outside, INSIDE[0]], 2)
    sided = _sided(len(splats[0]))
    batch = _sums(splats, sided, vm, K)
    assert batch[0, 0] == 0 and (batch[0, 1:] > 0).all()
    assert torch.equal(batch, _brute_force(splats, sided, vm, K))


def test_one_position_one_heading_twice():
    splats = _room()
    vm, K = _cameras([INSIDE[1]], 1)
    sided = _sided(len(splats[0]))
    twice = _sums(splats, sided, vm.expand(2, 4, 4).contiguous(), K.expand(2, 3, 3).contiguous())
    assert torch.equal(twice, _sums(splats, sided, vm, K).expand(2, 2))


def test_empty_map():
    splats = [t[:0] for t in _room(per_face=1)]
    vm, K = _cameras(INSIDE, 2)
    assert torch.equal(_sums(splats, torch.zeros(0, 2), vm, K), torch.zeros(2, len(vm), dtype=torch.float64))


def test_sums_do_not_depend_on_the_thread_count():
    splats = _room(seed=3)
    vm, K = _cameras(INSIDE, 6)
    sided = _sided(len(splats[0]), seed=4)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)  # the extension shares torch's OpenMP runtime
        one = _sums(splats, sided, vm, K, floor=0.3)
        torch.set_num_threads(2)
        two = _sums(splats, sided, vm, K, floor=0.3)
    finally:
        torch.set_num_threads(before)
    assert torch.equal(one, two)
