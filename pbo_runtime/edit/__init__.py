"""Checked changes to a description, and the one checked write-back: live saves, the canvas, the workspace."""
