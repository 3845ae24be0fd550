"""What the runtime tells about a file or a run: graph, lexicon, schema, data logs read back, plots of a run."""
