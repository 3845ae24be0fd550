"""The MuJoCo arm's "hardware registers": one shared-memory segment, laid out like a VME board's.

The plant creates the segment (0600, must not exist) and owns it; the driver attaches by name.
Nothing here takes a cross-process lock. Each block has one writer and a seqlock:

- state (q, qd, sim time, step count): written by the plant. It makes `STATE_SEQ` odd, writes,
  makes it even again; a reader copies between two equal even reads of `STATE_SEQ`.
- command (tau, q_cmd): written by the driver the same way with `CMD_SEQ`, so `CMD_SEQ // 2` counts
  the commands written.
- `BRAKE` and `MODE` are single aligned words written by the driver, read by the plant each step.
  `MODE` says which command registers the plant applies (tau in torque mode, q_cmd in position
  mode); a driver writes it when it releases the brakes, i.e. when it takes the arm (see
  `MujocoArmDriver.release_brakes` for how two drivers of different modes are kept apart).
- constants (ARM, EE: the arm's joint table and end effector, `pbo_runtime.objects.arm`): written
  once by the plant before it publishes the first state.
- target (version 2): the world pose of the plant's moving target marker (position m, rotation
  vector rad), what a camera sees; written by the plant with the state, under `STATE_SEQ`.
  `TARGET` is 1 when the plant has a target (plant option `target:`), else 0 and the block
  stays zero.
- board (version 3): the simulated I/O boards in the same rack (TR §4.6.1), served by the plant:
  an 8-channel 16-bit ADC (`adc`, int16 counts, +-10 V full scale), a 4-channel 16-bit DAC (`dac`,
  int16 counts, +-10 V) and a 16-channel parallel port (`pio_in`, the lines devices drive, and
  `pio_out`, the lines drivers drive; uint16 each). The plant converts every ADC channel each step
  under `BOARD_SEQ` (a seqlock, as for the state); each DAC channel and each parallel-port line
  word is one aligned word with one writer (the device database lends a channel to one task), so
  they need no lock. What the plant wires to them (see `plant`): the wrist force/torque sensor of
  vendor A to parallel-port channels 0-7, that of vendor B to ADC channels 0-5, and DAC channels
  0-1 back to ADC channels 6-7 (a loopback cable).

Aligned 8-byte words are read and written whole, and x86 keeps stores in program order (TSO),
so the seqlocks need no fences there. Layout (byte offsets, n = ndof, all little-endian):

    0    header, 16 words of 8 bytes (word index below)
    128  state:    q[n], qd[n]                  float64
    S    command:  tau[n], q_cmd[n]             float64, S = 128 + 16 n rounded up to 64
    C    constant: ARM[n,29], EE[8]              float64
    T    target:   pose[6] (x, y, z, rx, ry, rz), float64, T = C + 8 (29 n + 8) rounded up to 64
    B    board:    adc[8] int16 at B, dac[4] int16 at B + 64, pio_in[16] uint16 at B + 128,
                   pio_out[16] uint16 at B + 192; B = T + 48 rounded up to 64
"""

from __future__ import annotations

import contextlib
import mmap
from dataclasses import dataclass

import numpy as np
import posix_ipc

from pbo_runtime import Arm, PboError, attach_segment, create_segment

MAGIC = int.from_bytes(b"PBOARMRG", "little")
VERSION = 4  # 2: the target block and the TARGET word; 3: the board block and BOARD_SEQ; 4: ARM and EE

# Header words: u64 unless marked f64.
W_MAGIC = 0
W_VERSION = 1
W_NDOF = 2
W_STATE_SEQ = 3  # seqlock of the state block (odd while the plant writes)
W_SIM_TIME = 4  # f64, s, published under STATE_SEQ
W_STEP_COUNT = 5  # plant steps taken, published under STATE_SEQ
W_CMD_SEQ = 6  # seqlock of the command block (odd while the driver writes)
W_BRAKE = 7  # 1: brakes engaged (the plant holds the braked pose); the plant starts at 1
W_MODE = 8  # which command registers the plant applies, MODE_* below
W_TIMESTEP = 9  # f64, s, constant
W_PLANT_PID = 10  # the owning plant's pid, for diagnostics
W_TARGET = 11  # 1: the plant moves a target and publishes its pose in the target block; constant
W_BOARD_SEQ = 12  # seqlock of the ADC block (odd while the plant converts)
W_BOARD_STEP = 13  # the plant step of the last ADC conversion, published under BOARD_SEQ
HEADER_WORDS = 16

# The I/O boards (version 3).
ADC_CHANNELS = 8
DAC_CHANNELS = 4
PIO_CHANNELS = 16
ANALOG_FULL_SCALE = 10.0  # V: the ADC and the DAC span -10 V .. +10 V in int16 counts
VOLTS_PER_COUNT = ANALOG_FULL_SCALE / 32768.0

MODE_NONE = 0  # no driver has claimed the arm: the plant applies no torque
MODE_TORQUE = 1
MODE_POSITION = 2  # q_cmd registers, tracked by the plant's joint servo
MODES = {"torque": MODE_TORQUE, "position": MODE_POSITION}  # what drivers may ask for
MODE_NAMES = {MODE_NONE: "none", MODE_TORQUE: "torque", MODE_POSITION: "position"}

_CACHE_LINE = 64


class DeviceError(PboError):
    """A device's registers are missing, of another layout, or stuck mid-write."""


def _align(offset: int) -> int:
    return -(-offset // _CACHE_LINE) * _CACHE_LINE


@dataclass(frozen=True)
class RegisterLayout:
    """Byte offsets of each register block for an arm of `ndof` joints."""

    ndof: int
    state: int
    command: int
    constant: int
    target: int
    board: int
    size: int

    @classmethod
    def for_ndof(cls, ndof: int) -> RegisterLayout:
        if ndof < 1:
            raise ValueError(f"ndof must be >= 1, got: {ndof}")
        state = HEADER_WORDS * 8
        command = _align(state + 2 * ndof * 8)  # own cache line: another process writes it
        constant = _align(command + 2 * ndof * 8)
        target = _align(constant + (ndof * Arm.WIDTH + Arm.EE_WIDTH) * 8)
        board = _align(target + 6 * 8)
        size = board + 4 * _CACHE_LINE  # adc, dac, pio_in, pio_out: each its own line (different writers)
        return cls(ndof, state, command, constant, target, board, size)


class Registers:
    """Views over one mapping of the segment: header words, and numpy arrays per register.

    The views hold the mapping open; `release()` drops them so the mapping can be closed.
    """

    def __init__(self, mapping: mmap.mmap, layout: RegisterLayout) -> None:
        self.layout = layout
        self._mapping: mmap.mmap | None = mapping
        n = layout.ndof
        raw = memoryview(mapping)
        header = raw[: HEADER_WORDS * 8]
        self._views: list[memoryview[int] | memoryview[float]] = [raw, header]
        # memoryview item access is the cheapest way to read or write one word from Python.
        self.words = header.cast("Q")
        self.reals = header.cast("d")
        self._views += [self.words, self.reals]

        def block(offset: int, count: int) -> np.ndarray:
            return np.frombuffer(mapping, dtype=np.float64, count=count, offset=offset)

        self.q = block(layout.state, n)
        self.qd = block(layout.state + 8 * n, n)
        self.tau = block(layout.command, n)
        self.q_cmd = block(layout.command + 8 * n, n)
        self.arm = block(layout.constant, Arm.WIDTH * n).reshape(n, Arm.WIDTH)
        self.ee = block(layout.constant + 8 * Arm.WIDTH * n, Arm.EE_WIDTH)
        self.target = block(layout.target, 6)
        board = layout.board
        self.adc = np.frombuffer(mapping, dtype=np.int16, count=ADC_CHANNELS, offset=board)
        self.dac = np.frombuffer(mapping, dtype=np.int16, count=DAC_CHANNELS, offset=board + _CACHE_LINE)
        self.pio_in = np.frombuffer(mapping, dtype=np.uint16, count=PIO_CHANNELS, offset=board + 2 * _CACHE_LINE)
        self.pio_out = np.frombuffer(mapping, dtype=np.uint16, count=PIO_CHANNELS, offset=board + 3 * _CACHE_LINE)

    def release(self) -> None:
        """Drop every view, then close the mapping (idempotent)."""
        if self._mapping is None:
            return
        for name in ("q", "qd", "tau", "q_cmd", "arm", "ee", "target", "adc", "dac", "pio_in", "pio_out",
                     "words", "reals"):
            self.__dict__.pop(name, None)
        for view in reversed(self._views):
            view.release()
        self._views.clear()
        mapping, self._mapping = self._mapping, None
        # Someone kept a view (e.g. a test holding `registers.q`): the mapping goes when it does.
        with contextlib.suppress(BufferError):
            mapping.close()


def create_registers(name: str, ndof: int) -> tuple[posix_ipc.SharedMemory, Registers]:
    """Create the segment (0600, exclusive) with its header; the creator fills the constants."""
    layout = RegisterLayout.for_ndof(ndof)
    try:
        shm, mapping = create_segment(name, layout.size)
    except posix_ipc.ExistentialError:
        raise DeviceError(
            f"register segment {name!r} already exists; another plant owns it, or a dead run left it "
            "(a new run of the subsystem removes leftovers)"
        ) from None
    registers = Registers(mapping, layout)
    registers.words[W_VERSION] = VERSION
    registers.words[W_NDOF] = ndof
    registers.words[W_BRAKE] = 1
    registers.words[W_MODE] = MODE_NONE
    return shm, registers


def attach_registers(name: str) -> Registers:
    """Map an existing segment, checking that it is an arm register file of this layout."""
    try:
        mapping = attach_segment(name)
    except posix_ipc.ExistentialError:
        raise DeviceError(
            f"no register segment {name!r}: the plant that owns it is not running (drivers attach, never create)"
        ) from None
    header_size = HEADER_WORDS * 8
    if len(mapping) < header_size:
        mapping.close()
        raise DeviceError(
            f"register segment {name!r} is {len(mapping)} bytes, smaller than the {header_size}-byte header"
        )
    magic, version, ndof = np.frombuffer(mapping, dtype=np.uint64, count=3).tolist()
    # The plant writes the magic last, so a half-made segment is refused rather than misread.
    problem = ""
    if magic != MAGIC:
        problem = f"magic is {magic:#x}, expected {MAGIC:#x} (not an arm register file, or not ready yet)"
    elif version != VERSION:
        problem = f"layout version is {version}, expected {VERSION}"
    elif len(mapping) < RegisterLayout.for_ndof(ndof).size:
        problem = f"size {len(mapping)} is too small for {ndof} joints"
    if problem:
        mapping.close()
        raise DeviceError(f"register segment {name!r}: {problem}")
    return Registers(mapping, RegisterLayout.for_ndof(ndof))
