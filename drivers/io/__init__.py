"""Reconfigurable I/O device drivers (TR §4.6.1): the simulated ADC, DAC and parallel port."""
