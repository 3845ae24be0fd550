"""The `pbo` command's exit statuses, as the README lists them."""

EXIT_OK = 0
EXIT_CONFIG = 1  # the file has errors, or the arguments were refused
EXIT_RUN = 2  # the run failed, or saw a fault
EXIT_INTERNAL = 3  # a bug: please report it
