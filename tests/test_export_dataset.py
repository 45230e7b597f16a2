"""`fly --export-dataset` (output.dataset): an active flight's captured RGB-D frames and poses as a
nerfstudio-style dataset that our own reader (and so nerfstudio's convention) opens, equal to the
frames the mapper trained on, and continued, not restarted, by a resumed run; and a run
checkpointed by an older FlightRecon is refused with one message."""

import pickle

import numpy as np
import pytest

from flightrecon.config import to_toml
from flightrecon.dataset import load_dataset
from flightrecon.errors import CheckpointError
from flightrecon.mapping.frames import expand_frame
from flightrecon.mission import Mission
from flightrecon.scenario import load_config

TINY = ["camera.width=80", "camera.height=60", "selector.scoring_width=40", "selector.scoring_height=30",
        "mapper.k_new=5", "mapper.k_replay=3", "evaluation.views=2", "evaluation.every=0", "budget.frames=3",
        "budget.initial_views=2", "output.record=false", "output.dataset=true", "selector.method=random"]


@pytest.mark.slow
def test_dataset_holds_the_frames_the_mapper_trained_on_across_a_resume(tmp_path):
    import torch

    cfg = load_config("demo", TINY)
    first = Mission(cfg, tmp_path, progress=False)
    first.step()
    first.step()  # "killed" after two frames: the checkpoint and the dataset's index hold two
    assert len(load_dataset(tmp_path / "dataset")) == 2
    mission = Mission.resume(tmp_path, progress=False)
    mission.run()
    ds = load_dataset(tmp_path / "dataset")
    assert len(ds) == 3 and len(mission.mapper.frames) == 3
    assert (tmp_path / "dataset" / "trajectory.csv").is_file()
    for i, stored in enumerate(mission.mapper.frames):
        frame = ds[i]
        rgb, depth = expand_frame(stored, torch.device("cpu"))
        np.testing.assert_array_equal(np.round(frame.rgb * 255), rgb.numpy() * 255)  # both 8-bit
        valid = depth[..., 0].numpy() > 0
        np.testing.assert_allclose(frame.depth[valid], depth[..., 0].numpy()[valid], atol=1e-3)  # mm steps
        np.testing.assert_allclose(frame.T_wc, stored.T_wc, atol=1e-9)
    times = [ds[i].time for i in range(3)]
    assert times == sorted(times) and times[0] > 0  # simulated seconds at capture, after the take-off


def test_a_run_checkpointed_in_the_old_pickle_format_is_refused_with_one_message(tmp_path):
    cfg = load_config("demo", TINY)
    (tmp_path / "config.toml").write_text(to_toml(cfg))
    (tmp_path / "checkpoint.pkl").write_bytes(pickle.dumps({"mission": "old"}))
    with pytest.raises(CheckpointError, match=r"checkpoint\.pkl.*older FlightRecon \(pickle format\)"):
        Mission.resume(tmp_path, progress=False)
    with pytest.raises(CheckpointError, match=r"checkpoint\.pkl"):
        Mission(cfg, tmp_path, progress=False).step()  # nor is a new run started beside it
