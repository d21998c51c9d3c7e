"""Spec -> CasADi symbolic model -> generated C (see acroboter.codegen.emit_c)."""
