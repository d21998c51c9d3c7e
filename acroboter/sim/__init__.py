"""What the controllers act on and the loop that joins them: the plants (own RK4 with cables that only pull,
MuJoCo), statics (the start equilibrium), sensing, the closed loop, its Result, path feasibility."""
