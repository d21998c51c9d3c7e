"""Spec -> CasADi symbolic model -> generated C (see codegen.generate)."""
