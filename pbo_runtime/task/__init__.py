"""A task's lifecycle (TR Figure 11) and its precomputed per-cycle transfer."""
