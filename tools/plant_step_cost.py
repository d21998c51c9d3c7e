"""What the plant's physical parameters cost: `python tools/plant_step_cost.py [SPEC]`.

Times one generated RK4 step (`plant_step`, one pre-bound ctypes call) of the shipped library,
whose physical parameters are a run-time input, against the same step generated with them folded
in as constants and a numeric M⁻¹ (GenerationContext(parametric_plant=False): the plant before
plant parameters existed), on the same states and inputs of an MLM run, interleaved passes, the
quietest pass of each (as `acroboter bench`). Prints both medians and their ratio.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from acroboter.api.crane import Crane
from acroboter.codegen.emit_c import generate
from acroboter.process.locations import example_spec
from acroboter.runtime.cache import load_model
from acroboter.sim.plant import Plant


def step_times(plant: Plant, states, inputs, table, substeps: int, h: float, calls: int = 20) -> float:
    """Median per-call wall time (s) of the bare generated step over the states."""
    clock = time.perf_counter
    call, point = plant._step.call, plant._step.point_input
    times = []
    for k, (x, u) in enumerate(zip(states, inputs, strict=True)):
        plant._x[:], plant._u[:] = x, u
        plant._settings[:] = (h, plant.zeta, plant.omega)
        point(plant._stage_input, table.ctypes.data + 2 * k * substeps * table.strides[0])
        t0 = clock()
        for _ in range(calls):
            call()
        times.append((clock() - t0) / calls)
    point(plant._stage_input, plant._stage.ctypes.data)
    return float(np.median(times))


def main(argv: list[str]) -> int:
    crane = Crane.from_toml(argv[0] if argv else example_spec("acroboter"))
    spec, sim = crane.spec, crane.spec.simulation
    with tempfile.TemporaryDirectory() as tmp:
        generate(spec, Path(tmp), parametric_plant=False)
        folded = load_model(spec, generated_dir=Path(tmp))  # compiled into the cache (once per version)
        run = crane.simulate("mlm", duration=min(10.0, crane.path.duration), warm_up=0)
        substeps = round(1.0 / (spec.controller.rate_hz * sim.step))
        plants = {"folded": Plant(folded, crane.path, sim.baumgarte_zeta, sim.baumgarte_omega),
                  "parametric": Plant(crane.model, crane.path, sim.baumgarte_zeta, sim.baumgarte_omega)}
        table = plants["folded"].stage_table(0.0, sim.step, len(run.time) * substeps)
        states = [np.concatenate([q, qd, np.zeros(3)]) for q, qd in zip(run.q, run.qd, strict=True)][:500]
        best = {name: np.inf for name in plants}
        for _ in range(7):  # interleaved passes: a slow stretch of a shared machine hits both alike
            for name, plant in plants.items():
                best[name] = min(best[name], step_times(plant, states, run.u[:500], table, substeps, sim.step))
    print(f"{spec.name}: plant_step median {1e6 * best['folded']:.2f} us with the parameters folded in, "
          f"{1e6 * best['parametric']:.2f} us with them as an input: ratio {best['parametric'] / best['folded']:.3f}")
    print(f"  folded: {folded.library_path}\n  parametric: {crane.model.library_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
