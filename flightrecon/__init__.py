"""FlightRecon: active scene reconstruction with a simulated quadrotor.

The few calls a script needs (docs/python_api.md, examples/scripted_flight.py):

    cfg = flightrecon.load_config("demo", ["budget.frames=10"])   # a scenario, validated
    mission = flightrecon.Mission(cfg, "runs/mine")              # or Mission.resume(run_dir)
    row = mission.step()                                         # one frame of the closed loop
    scores = mission.score_candidates(mission.plan_candidates())
    metrics = mission.finish()                                   # map.ply, metrics.json
    out = flightrecon.render_map(flightrecon.load_map(path), T_wc, K, width, height)
    eval = flightrecon.evaluate_run("runs/mine")                 # eval.json

and, for a view-selection method of one's own, `Selector`, `MapView`, `Observation`, `option` and
`register_selector` (docs/selectors.md).

MuJoCo binds its OpenGL backend when first imported, so the package chooses a headless one (EGL,
else OSMesa; flightrecon.headless_gl) before any submodule can import mujoco. A user's own
MUJOCO_GL wins. For the same reason the OpenMP wait policy (flightrecon.threads: waiting threads spin
briefly, then sleep, so a flight does not collapse when other work shares the cores) is set here,
before any submodule can import torch; a user's own OMP_WAIT_POLICY or GOMP_SPINCOUNT wins. The names
above are imported on first use, so `import flightrecon` stays light.
"""

from importlib import import_module
from typing import Any

from flightrecon.headless_gl import set_default_backend as _set_default_backend
from flightrecon.threads import apply_wait_policy as _apply_wait_policy

_set_default_backend()
_apply_wait_policy()

__version__ = "0.1.0"

_API = {
    "load_config": "flightrecon.scenario",
    "option": "flightrecon.config",
    "ScenarioConfig": "flightrecon.config",
    "Mission": "flightrecon.mission",
    "load_map": "flightrecon.mapping.ply",
    "save_map": "flightrecon.mapping.ply",
    "render_map": "flightrecon.evaluation.map_metrics",
    "evaluate_run": "flightrecon.experiments.run_eval",
    "Selector": "flightrecon.active.protocol",
    "MapView": "flightrecon.active.protocol",
    "Observation": "flightrecon.active.protocol",
    "register_selector": "flightrecon.active.registry",
    "FlightReconError": "flightrecon.errors",
}
__all__ = sorted(_API)


def __getattr__(name: str) -> Any:
    if name not in _API:
        raise AttributeError(f"module 'flightrecon' has no attribute {name!r}")
    attr = "register" if name == "register_selector" else name
    return getattr(import_module(_API[name]), attr)


def __dir__() -> list[str]:
    return sorted(list(globals()) + __all__)
