"""A period the plant's step cannot resolve, flown again at a finer step: the own plant's step per crane and instant.

The plant integrates with fixed-step RK4 at the spec's `simulation.step`. That step suits the cranes it was chosen
for; a generated crane can pass through a configuration whose motion is fast for it. Generated crane_217 (a 5.9 g
drum) at 0.16-0.19 s of a plant-fuzz drive goes through a snap whose growth rate rises from 57 to 220 1/s within
10 ms: RK4 at 2 ms loses the motion there, and the energy balance, which held to 1e-7 J, broke its bound by 35x
(docs/plant-fuzz-cranes.md). At 1 ms the same drive holds it.

The rule. The energy balance (acroboter.sim.plant) is an error indicator the plant already computes at the end of
every control period. Where its residual changes within one period by more than 1 % of its bound (REFINE_RATE:
0.5 of it per second of flight), or an invariant breaks inside the period (the balance at an event, a slack cable
stretched, a taut one pushing, no consistent cable state: acroboter.sim.cable_events), the period is flown again
from its start at h/2, then h/4, ... down to h / 2**MAX_HALVINGS. The first step whose period keeps within that
share and breaks nothing is kept; the finest one's is kept whatever its share (the bound itself is still checked at
its end). Generated crane_222: at 2 ms a cable event inside a fast period chattered 250 times; refined, it holds.
Nothing in a period that holds is touched: on every shipped crane's runs a period's residual changes by
~1e-8 J against a threshold of ~3e-5 J, so their numbers are unchanged to the bit. The periods refined and the
finest step are counted (`refined_periods`, `finest_step`); a run's summary reports them. A period that no finer
step resolves raises the plant's error at the finest step, as before (the energy's naming that step).

Why a period and not a substep: the energy residual is checked per period (per event substep inside it), the
rollback is one saved state, and the cost falls only on the periods that need it.
"""

from __future__ import annotations

import numpy as np

from .cable_events import SimulationError

# A stretch of flight whose energy residual changes faster than this share of its bound per second is refined:
# 1 % of it in a 20 ms control period. A rate, so that one advance of a period and ten of its substeps (the plant
# fuzz's) are held alike.
REFINE_RATE = 0.5  # 1/s
MAX_HALVINGS = 4  # down to h/16


class EnergyBalanceError(RuntimeError):
    """Raised inside a period the plant then refines (never seen outside acroboter.sim.plant)."""


class StepRefinement:
    """The period-level refinement of acroboter.sim.plant.Plant (a mixin; see the module docstring)."""

    def _init_refinement(self) -> None:
        n_cables = len(self.cable_names)
        self._saved_x = np.zeros(self.state_size)
        self._saved_active = np.zeros(n_cables)
        self._saved_transitions = np.zeros(n_cables, dtype=np.int64)
        self._saved_scalars: tuple = ()
        self.refining = False  # inside a period that a finer step may fly again
        self._refined_to: float | None = None  # s, the step of the period being flown again
        self._period_residual = 0.0
        self.refined_periods = 0  # periods flown again at a finer step
        self.finest_step: float | None = None  # s, the finest step a refined period kept

    def _save_period(self, x: np.ndarray) -> None:
        self._saved_x[:] = x
        self._saved_active[:] = self._active
        self._saved_transitions[:] = self.transitions
        self._saved_scalars = (len(self.events), self.impact_energy, self._peak_kinetic, self._peak_terms,
                               self.energy_residual, self._energy_start, self.closing, self.energy_checked_from)

    def _restore_period(self, x: np.ndarray) -> None:
        x[:] = self._saved_x
        self._active[:] = self._saved_active
        self.transitions[:] = self._saved_transitions
        (events, self.impact_energy, self._peak_kinetic, self._peak_terms, self.energy_residual, self._energy_start,
         self.closing, self.energy_checked_from) = self._saved_scalars
        del self.events[events:]

    def _period_holds(self, x: np.ndarray, duration: float) -> bool:
        """Whether the `duration` s just flown keep the energy residual's change since the period's start within
        REFINE_RATE·duration of its bound; the residual in `_period_residual`. A period that started or ends
        closing the constraints is not judged: the residual is re-based where they close (Plant._check_energy), a
        jump that is no error."""
        self._period_residual = residual = self.energy_balance(x)
        _, _, _, _, before, _, started_closing, _ = self._saved_scalars
        if self.closing or started_closing:
            return True
        return abs(residual - before) <= REFINE_RATE * duration * self.energy_bound

    def _fly_period(self, x: np.ndarray, u: np.ndarray, h: float, table, first_step: int, steps: int,
                    t0: float) -> float:
        """The period [t0 + first_step·h, + steps·h] from x (in place), refined where it must be (module
        docstring); its end's energy residual. The check of it is the caller's."""
        self._save_period(x)
        start = t0 + first_step * h
        for halving in range(MAX_HALVINGS + 1):
            step, count = h / 2**halving, steps * 2**halving
            if halving:
                self._restore_period(x)
                self._refined_to = step
            # an invariant broken inside the period asks for a finer step, not an error; at the finest step tried
            # it raises as the plant always did
            self.refining = halving < MAX_HALVINGS
            try:
                if halving:
                    self._run_substeps(x, u, step, self.stage_table(start, step, count), 0, count, start)
                else:
                    self._run_substeps(x, u, h, table, first_step, steps, t0)
            except (EnergyBalanceError, SimulationError):
                if not self.refining:
                    raise
                continue
            finally:
                self.refining = False
            # (the finest step's period is kept whatever its share: the caller's check of the bound decides)
            if self._period_holds(x, steps * h) or halving == MAX_HALVINGS:
                if halving:
                    self.refined_periods += 1
                    self.finest_step = step if self.finest_step is None else min(self.finest_step, step)
                return self._period_residual
        raise AssertionError("unreachable: the finest step's period returns or raises")
