"""Spec -> CasADi symbolic model -> generated C (see acroboter.codegen.generate)."""
