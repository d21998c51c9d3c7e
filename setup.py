"""Ship the example specs and their checked-in generated C inside the wheel.

They live outside the package in the repository (model_spec/, generated/: one source of truth,
checked for freshness by `make check-generated`); the wheel build copies them to
acroboter/examples/{specs,generated}/ so an installed package finds them (acroboter.locations).
Everything else is in pyproject.toml.
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent


class BuildWithExamples(build_py):
    def run(self):
        super().run()
        if self.editable_mode:  # an editable install reads model_spec/ and generated/ in place
            return
        target = Path(self.build_lib) / "acroboter" / "examples"
        shutil.rmtree(target, ignore_errors=True)
        (target / "specs").mkdir(parents=True)
        for spec in sorted((ROOT / "model_spec").glob("*.toml")):
            shutil.copy2(spec, target / "specs" / spec.name)
        generated = target / "generated"
        for folder in sorted((ROOT / "generated").iterdir()):
            if folder.is_dir() and not folder.name.startswith("."):
                shutil.copytree(folder, generated / folder.name)


setup(cmdclass={"build_py": BuildWithExamples})
