"""The simulated arm: a MuJoCo plant exposing registers in shared memory, and the driver tasks use."""

from __future__ import annotations
