"""acroboter: compiled crane dynamics, three inverse-dynamics controllers and a fixed-step plant.

    import acroboter

    crane = acroboter.Crane.from_toml(acroboter.example_spec("acroboter"))
    result = crane.simulate("penalty", duration=5.0)
    print(result.summary()["max_position_error_mm"])
    result.plot()

The names below load on first use, so `import acroboter` (and every command's --help) stays quick.
"""

import os

# The matrices here are tiny (tens of rows): BLAS threads only add hand-off cost, and on a loaded
# 2-core machine a threaded 27x27 triangular solve took 1 ms instead of 13 us. Set before numpy
# loads OpenBLAS; a user's explicit setting wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def _package_version() -> str:
    from importlib import metadata

    try:
        return metadata.version("acroboter")
    except metadata.PackageNotFoundError:  # run from a checkout that was never installed
        return "0+unknown"


__version__ = _package_version()

# public name -> the module that defines it
_EXPORTS = {
    "Crane": "acroboter.api.crane",
    "Controller": "acroboter.api.crane",
    "Equilibrium": "acroboter.sim.statics",
    "Result": "acroboter.sim.result",
    "Spec": "acroboter.model.spec",
    "SpecError": "acroboter.model.spec",
    "load_spec": "acroboter.model.spec",
    "example_spec": "acroboter.process.locations",
    "example_names": "acroboter.process.locations",
    "cache_dir": "acroboter.process.locations",
    "SampledTrajectory": "acroboter.control.path",
    "TrajectoryError": "acroboter.control.path",
    "EquilibriumError": "acroboter.sim.statics",
    "StaleModelError": "acroboter.runtime.compiled",
    "SimulationError": "acroboter.sim.plant",
    "SingularSystemError": "acroboter.control.controllers",
    "PlantParameterError": "acroboter.model.physical",
    "mjcf_xml": "acroboter.model.mjcf_model",
    "MujocoPlant": "acroboter.sim.mujoco_plant",
    "PlanningError": "acroboter.planning.ideal_motion",
    "StaticLimitError": "acroboter.planning.checks",
    "CertificateError": "acroboter.planning.planner",
}

__all__ = ["__version__", *sorted(_EXPORTS)]


def __getattr__(name: str):
    if name in _EXPORTS:
        from importlib import import_module

        value = getattr(import_module(_EXPORTS[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'acroboter' has no attribute '{name}'")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
