"""Viewpoint library: the paper's 198 default candidates, GauSS-MI's pose convention, user TOML files."""

from __future__ import annotations

import math

import numpy as np
import pytest

from flightrecon.errors import ConfigError
from flightrecon.planning.library import default_library, in_bounds, load_library


def test_default_library_has_the_papers_198_distinct_candidates():
    lib = load_library("default")
    assert len(lib) == 198
    pos, yaw = lib.poses(np.array([1.0, -2.0, 1.2]), 0.7)
    assert len(np.unique(np.round(np.c_[pos, yaw], 6), axis=0)) == 198
    assert np.all(np.abs(yaw) <= math.pi + 1e-12)
    d_xy = np.linalg.norm(pos[:, :2] - [1.0, -2.0], axis=1)
    assert set(np.round(d_xy, 6)) == {0.0, 0.3, 0.6}
    assert set(np.round(pos[:, 2] - 1.2, 6)) == {-0.4, 0.0, 0.4}
    headings = np.sort(np.unique(np.round(np.degrees(yaw - 0.7) % 360, 6)))
    np.testing.assert_allclose(headings, np.arange(0, 360, 20), atol=1e-6)


def test_offsets_follow_gaussmi_convention():
    # GauSS-MI's library (docs/baselines.md): yaw' = yaw + dyaw, position + (-dy sin yaw', dy cos yaw', dz).
    lib = default_library()
    p0, yaw0 = np.array([0.2, 0.1, 1.0]), -1.1
    pos, yaw = lib.poses(p0, yaw0)
    for (fwd, left, up, dyaw), p, y in zip(lib.offsets, pos, yaw):
        if fwd != 0.0:
            continue
        yn = yaw0 + dyaw
        expect = p0 + [-left * math.sin(yn), left * math.cos(yn), up]
        np.testing.assert_allclose(p, expect, atol=1e-12)
        assert math.remainder(y - yn, 2 * math.pi) == pytest.approx(0.0, abs=1e-12)
    # Forward steps move along the new heading.
    k = int(np.nonzero((lib.offsets[:, 0] > 0.5))[0][3])
    yn = yaw0 + lib.offsets[k, 3]
    np.testing.assert_allclose(pos[k], p0 + 0.6 * np.array([math.cos(yn), math.sin(yn), 0.0]), atol=1e-12)


def test_user_library_from_toml(tmp_path):
    f = tmp_path / "mine.toml"
    f.write_text("[[candidate]]\nforward = 0.5\nyaw_deg = 90\n\n[[candidate]]\nup = -0.2\n")
    lib = load_library(str(f))
    assert len(lib) == 2 and lib.name == "mine"
    pos, yaw = lib.poses(np.zeros(3), 0.0)
    np.testing.assert_allclose(pos, [[0.0, 0.5, 0.0], [0.0, 0.0, -0.2]], atol=1e-12)
    np.testing.assert_allclose(yaw, [math.pi / 2, 0.0])


@pytest.mark.parametrize("text, words", [
    ("[[candidate]]\nforwrd = 0.5\n", ["candidate 0", "forwrd"]),
    ("[[candidate]]\nup = 'high'\n", ["candidate 0", "'up'"]),
    ("candidates = 3\n", ["unknown key 'candidates'"]),
    ("", ["no [[candidate]]"]),
    ("[[candidate]\n", ["not valid TOML"]),
])
def test_bad_user_library_names_the_file_and_key(tmp_path, text, words):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_library(str(f))
    msg = str(err.value)
    assert "planner.library" in msg and str(f) in msg
    for w in words:
        assert w in msg


def test_missing_library_file():
    with pytest.raises(ConfigError, match="candidate file not found"):
        load_library("/nonexistent/lib.toml")


def test_in_bounds_drops_candidates_outside_the_workspace():
    pos, _ = default_library().poses(np.array([0.0, 0.0, 0.3]), 0.0)
    keep = in_bounds(pos, np.array([[-5.0, -5.0, 0.0], [5.0, 5.0, 3.0]]))
    np.testing.assert_array_equal(keep, pos[:, 2] >= 0.0)
    assert (~keep).sum() == 18  # the 18 headings of the step down


def test_no_stay_library_is_the_default_without_the_current_pose():
    lib = load_library("no_stay")
    pos, yaw = lib.poses(np.array([1.0, -2.0, 1.2]), 0.7)
    assert len(lib) == 197
    assert not np.any(np.all(np.isclose(np.c_[pos, yaw], [1.0, -2.0, 1.2, 0.7]), axis=1))
    turns_in_place = np.isclose(np.linalg.norm(pos - [1.0, -2.0, 1.2], axis=1), 0.0)
    assert turns_in_place.sum() == 17  # the other 17 headings of the current position stay


def test_moving_library_has_no_candidate_at_the_current_position():
    lib = load_library("moving")
    pos, yaw = lib.poses(np.array([1.0, -2.0, 1.2]), 0.7)
    assert len(lib) == 198 - 18
    step = np.linalg.norm(pos - [1.0, -2.0, 1.2], axis=1)
    assert step.min() == pytest.approx(0.3)  # the nearest views are one GauSS-MI unit away
    assert len(np.unique(np.round(np.c_[pos, yaw], 6), axis=0)) == 180


def test_gaussmi_library_counts_and_reach_of_its_public_code():
    # active_manage.py init_view_lib: 5x3x3-3 basic, 4x3 high, 6x4 wide-turn and 4x2x2 aggressive samples (its comment says 8 of the last; it builds 16)
    lib = load_library("gaussmi")
    assert len(lib) == (5 * 3 - 1) * 3 + 4 * 3 + 6 * 4 + 4 * 2 * 2 == 94
    p0, yaw0 = np.array([0.0, 0.0, 1.5]), 0.3
    pos, yaw = lib.poses(p0, yaw0)
    step = pos - p0
    lateral = np.linalg.norm(step[:, :2], axis=1)
    assert np.isclose(lateral.max(), 1.2) and np.isclose(np.abs(step[:, 2]).max(), 1.2)
    assert np.all(lateral + np.abs(step[:, 2]) > 0.25)  # never the current position
    turns = np.degrees(np.array([math.remainder(y - yaw0, 2 * math.pi) for y in yaw]))
    assert set(np.round(np.abs(turns)).astype(int)) == {0, 40, 80, 120, 160}
    # each move is sideways in the turned frame (GauSS-MI: + (-dy sin yaw', dy cos yaw', dz))
    heading = np.c_[np.cos(yaw), np.sin(yaw)]
    np.testing.assert_allclose(np.sum(step[:, :2] * heading, axis=1), 0.0, atol=1e-12)
    assert len(np.unique(np.round(np.c_[pos, yaw], 6), axis=0)) == 94
