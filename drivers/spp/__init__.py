"""The special-purpose processor (TR §4.6.3): an emulated floating-point accelerator, its driver and its routines."""
