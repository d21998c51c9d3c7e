"""The hypothesis strategy of generated cranes: acroboter.model.crane_generator's own function, its numbers drawn by
hypothesis (so that a failing crane shrinks towards the simplest one: fewer winches, the ranges' lower ends)."""

from __future__ import annotations

from hypothesis import strategies as st

from acroboter.model.crane_generator import WINCHES, generated_crane


class HypothesisDraw:
    """The generator's Draw, from a composite strategy's `draw`."""

    def __init__(self, draw):
        self.draw = draw

    def uniform(self, low: float, high: float) -> float:
        return self.draw(st.floats(low, high, allow_nan=False, allow_infinity=False))

    def integer(self, low: int, high: int) -> int:
        return self.draw(st.integers(low, high))


@st.composite
def crane_specs(draw, name: str = "crane_drawn", winches: tuple[int, int] = WINCHES) -> dict:
    """A generated crane's spec (the TOML tables), with a number of winch cables in `winches`."""
    return generated_crane(HypothesisDraw(draw), name, winches)
