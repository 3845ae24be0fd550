"""Between processes: shared segments, pid liveness, queues, typed messages, child processes."""
