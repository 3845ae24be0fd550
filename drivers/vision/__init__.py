"""The simulated vision subsystem: a camera that reports the plant's moving target."""
