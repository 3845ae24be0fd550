"""What a file predicts: the bus load (TR eq. 1-2), schedulability, allocation of tasks to RTPUs, placement."""
