"""Retiming a path under the actuator limits: the time-optimal problem, its checks and its result."""
