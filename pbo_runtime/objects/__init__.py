"""The port-based object's contract: modules, ports, drivers and the library registry."""
