"""acroboter: compiled crane dynamics, three inverse-dynamics controllers and a fixed-step plant."""
