"""One exception type for bad input, so the CLI can print one line and exit non-zero."""


class InputError(Exception):
    """Bad user input. The message names the file and line, or the frame, that is wrong."""


class RunFailed(Exception):
    """A run failed for a reason other than bad input (a bug, out of memory, disk full ...).
    The message is one line and says where the partial outputs were kept."""


def did_you_mean(word: str, choices) -> str:
    """``" (did you mean 'p_miss'?)"`` when ``word`` is close to one of ``choices`` (difflib's
    ratio >= 0.6, the closest first), else ``""``: the hint every "unknown NAME" message
    appends, on the command line and in Python alike."""
    import difflib

    near = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1, cutoff=0.6)
    return f" (did you mean {near[0]!r}?)" if near else ""
