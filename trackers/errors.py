"""One exception type for bad input, so the CLI can print one line and exit non-zero."""


class InputError(Exception):
    """Bad user input. The message names the file and line, or the frame, that is wrong."""
