"""Real and simulated clocks, and the lockstep barrier of the simulated one."""
