"""The two simulated wrist force/torque sensors, as their vendors' manuals describe them (TR §4.6.2).

Both measure the same thing, the wrench the environment applies to the tool at the sensor: force
(N) and torque about the sensor's origin (N m), in the sensor frame, which is the arm's tool
frame (DH frame n, the `ee` site; the MJCF's `ft` site). What differs is the interface:

Vendor A, a digital sensor on a parallel port, 8 channels (ports) of 16 lines each:

    channel 0-5  in    Fx, Fy, Fz, Tx, Ty, Tz: 16-bit two's complement counts
    channel 6    in    ACK: the request number the data answers
    channel 7    in    STATUS: bit 0 powered, bit 1 a reading clipped at full scale
    channel 7    out   REQUEST: write a new number to latch a new reading (the strobe)

  The sensor latches a reading when REQUEST changes (at the plant's next step), writes the six
  data words, then ACK = REQUEST. Fixed scale: `FORCE_PER_COUNT` N, `TORQUE_PER_COUNT` N m.

Vendor B, an analog strain-gauge sensor on 6 ADC channels. Its gauges give voltages

    v = C^-1 w + offset          (w: the wrench; C and offset from the sensor's calibration sheet)

  and its driver computes w = C (v - offset). `CALIBRATION` and `OFFSET` below are the sheet of
  the sensor the plant simulates; a device's YAML carries them as options.
"""

from __future__ import annotations

import numpy as np

# --- vendor A: parallel port -----------------------------------------------------------------------
A_CHANNELS = 8  # parallel-port channels the sensor's cable takes
A_DATA = 0  # first data channel (6 of them)
A_ACK = 6
A_STATUS = 7
A_REQUEST = 7  # an output line word
A_STATUS_POWERED = 1
A_STATUS_CLIPPED = 2
FORCE_PER_COUNT = 0.02  # N per count: +-655 N full scale
TORQUE_PER_COUNT = 0.0005  # N m per count: +-16.4 N m full scale
A_SCALE = np.array([FORCE_PER_COUNT] * 3 + [TORQUE_PER_COUNT] * 3)
A_SCALE.setflags(write=False)

# --- vendor B: analog, 6 ADC channels ---------------------------------------------------------------
B_CHANNELS = 6
# N/V (rows Fx, Fy, Fz) and N m/V (rows Tx, Ty, Tz); the off-diagonal terms are the gauges' crosstalk.
CALIBRATION = np.array([
    [40.0, 0.8, -0.4, 0.0, 0.0, 0.2],
    [-0.6, 40.0, 0.5, 0.0, 0.0, -0.3],
    [0.4, -0.2, 80.0, 0.0, 0.0, 0.0],
    [0.0, 0.02, 0.0, 4.0, 0.08, 0.0],
    [-0.02, 0.0, 0.0, -0.06, 4.0, 0.0],
    [0.0, 0.0, 0.01, 0.0, 0.0, 3.0],
])
OFFSET = np.array([0.012, -0.008, 0.025, 0.003, -0.004, 0.006])  # V: the gauges' output at no load
CALIBRATION.setflags(write=False)
OFFSET.setflags(write=False)
