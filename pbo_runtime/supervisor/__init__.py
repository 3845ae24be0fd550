"""Job control: the supervisor, its decisions, the stall watch, the plant host, applications."""
