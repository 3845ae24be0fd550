"""The global state variable table, the device database, and reading a live table."""
