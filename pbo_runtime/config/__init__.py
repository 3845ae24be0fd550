"""The YAML format: nodes with marks, units, expressions, the model, the loader, the checker, the bus model."""
