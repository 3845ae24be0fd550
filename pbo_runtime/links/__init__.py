"""Links between subsystems: specs, triple buffers, message queues, zenoh, the relay."""
