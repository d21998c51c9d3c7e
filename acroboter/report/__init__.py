"""What runs and studies write and show: summary and table, figures, the study figures, the robustness
report, the live viewer, the animation (scene, frames, encoders)."""
