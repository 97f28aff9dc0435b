"""One exception type for bad input, so the CLI can print one line and exit non-zero."""


class InputError(Exception):
    """Bad user input. The message names the file and line, or the frame, that is wrong."""


class RunFailed(Exception):
    """A run failed for a reason other than bad input (a bug, out of memory, disk full ...).
    The message is one line and says where the partial outputs were kept."""
