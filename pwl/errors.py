"""The one base class of pwl's user-facing errors.

Every error pwl raises on purpose for bad input (a database, log, spec, plant, table, zones
record, diagnosis or score file that cannot be used) derives from :class:`PwlError`, and its
message names the file, channel, key or value at fault. The CLI prints any of them as one line
``pwl COMMAND: error: ...`` and exits with :data:`EXIT_INPUT`; anything else is a bug, printed as
an internal error with :data:`EXIT_INTERNAL` (``pwl --debug`` shows the traceback of both).

Exit codes (documented in the README and ``pwl --help``):
"""
from __future__ import annotations

EXIT_OK = 0          #: done, nothing to report
EXIT_FINDINGS = 1    #: done, but something needs attention (a fault flagged, a log with too few
                     #: estimates, an item of a batch that failed: the message says which)
EXIT_INPUT = 2       #: unusable input or command line (the message names it); nothing written
EXIT_INTERNAL = 3    #: a bug in pwl (please report it with the ``--debug`` traceback)
EXIT_INTERRUPTED = 130

EXIT_CODES = {EXIT_OK: "success", EXIT_FINDINGS: "finished with findings (fault flagged, log with "
              "too few estimates, failed batch item)", EXIT_INPUT: "unusable input (named)",
              EXIT_INTERNAL: "internal error (a bug; rerun with --debug)",
              EXIT_INTERRUPTED: "interrupted"}


class PwlError(Exception):
    """Base of every named, user-facing pwl error (the message names what is wrong)."""


class UsageError(PwlError, ValueError):
    """Options or arguments that cannot be used together (the message says which and why)."""


class PwlWarning(UserWarning):
    """Input pwl used with a fallback the user should know about (the message names it), e.g.
    text cells in a numeric log column read as missing values."""
