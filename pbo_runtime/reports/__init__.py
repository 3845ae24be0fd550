"""What the runtime tells about a file: graph, lexicon, schema."""
