"""The warm-up before a flight loads every compiled kernel signature that the flight uses, so that
the first tick in the air does not stall the event loop (seconds of wall time on a busy machine)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import importlib.util

import pytest

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.skipif(importlib.util.find_spec("numba") is None,
                                reason="needs the fast extra (numba): pip install -e '.[fast]'")

# In a fresh interpreter: the dispatchers of this one may have signatures from other tests.
SCRIPT = textwrap.dedent("""
    import sys
    from uav_model.mission import load_mission
    from companion.app.flight_plan import prepare
    from companion.app.steering import clearance_here_m
    from companion.app.warmup import warm_up_planners
    from numba.core.dispatcher import Dispatcher
    import pickle
    from companion.planning import timed_route_jit
    from companion.planning.dwa import (distance_jit, evaluate_jit, geometry_jit, heading_jit, recovery_jit,
                                        sightline_jit)
    from companion.planning.obstacle_field import ObstacleField
    from companion.planning.flight.headless import simulate

    def loaded():  # the DWA's and the timed routes' compiled kernels: signatures per dispatcher
        return {f"{m.__name__}.{k}": len(v.signatures)
                for m in (distance_jit, evaluate_jit, geometry_jit, heading_jit, recovery_jit, sightline_jit,
                          timed_route_jit)
                for k, v in vars(m).items() if isinstance(v, Dispatcher)}

    mission = load_mission(sys.argv[1]).with_variant(sys.argv[2])
    plan = prepare(mission)
    warm_up_planners(plan)
    warm = loaded()
    assert sum(warm.values()) >= 3, warm
    # Every tick of a whole flight, moving and turning, on the plan as the live flight gets it:
    # made again in a child process (companion.app.offload), pickled back.
    coordinated = None if plan.coordinated is None else pickle.loads(pickle.dumps(plan.coordinated))
    simulate(mission, timed_routes=None if coordinated is None else coordinated.timed)
    field = ObstacleField.from_world(mission.world)
    clearance_here_m(10.0, 10.0, field.from_tracks(field.tracks_at(30.0)))  # the flight log's column
    later = loaded()
    print({n: later[n] - warm[n] for n in warm if later[n] != warm[n]})
""")


# The timed variant's b carries its sightline term only near a (sight_near_m): the warm-up must
# load that term's kernels too, though at the stations a is far away.
@pytest.mark.parametrize("mission, variant", [("missions/moving_obstacles.yaml", "astar-bdwa"),
                                              ("tests/data/small_swap.yaml", "astar-bdwa"),
                                              ("missions/small_reference.yaml", "astar-bdwa-timed")])
def test_the_flight_needs_no_kernel_signature_the_warm_up_did_not_load(mission, variant):
    done = subprocess.run([sys.executable, "-c", SCRIPT, str(ROOT / mission), variant], capture_output=True,
                          text=True, cwd=ROOT, timeout=240)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip() == "{}", f"signatures first needed in flight: {done.stdout}"


HEADLESS = textwrap.dedent("""
    import sys
    from numba.core.dispatcher import Dispatcher
    from uav_model.mission import load_mission
    from companion.app.warmup import warm_up_headless
    from companion.planning.flight.headless import simulate

    def loaded():
        return {f"{name}.{key}": len(value.signatures) for name, module in list(sys.modules.items())
                if name.startswith(("companion", "uav_model"))
                for key, value in vars(module).items() if isinstance(value, Dispatcher)}

    mission = load_mission(sys.argv[1]).with_variant(sys.argv[2])
    warm_up_headless(mission)  # the mission's variant, as simulate flies it
    warm = loaded()
    assert sum(warm.values()) >= 5, warm
    simulate(mission)
    later = loaded()
    print({k: later[k] - warm.get(k, 0) for k in later if later[k] != warm.get(k, 0)})
""")


@pytest.mark.parametrize("mission, variant", [("missions/paper_reference.yaml", "astar-bdwa"),
                                              ("missions/moving_obstacles.yaml", "astar-bdwa"),
                                              ("missions/small_reference.yaml", "astar-bdwa-timed")])
def test_a_timed_headless_flight_loads_no_compiled_code_after_the_warm_up(mission, variant):
    """``companion simulate`` starts its clock after :func:`warm_up_headless`: the speed it prints
    is the flight's, with no kernel loaded (let alone compiled) inside it."""
    done = subprocess.run([sys.executable, "-c", HEADLESS, str(ROOT / mission), variant], capture_output=True,
                          text=True, cwd=ROOT, timeout=240)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip() == "{}", f"compiled code first loaded in the timed flight: {done.stdout}"
