"""Which library log lines reach the console: set once per process of a command (light: imports only logging)."""

from __future__ import annotations

import logging

#: Library loggers held to errors in every process of a command: their warnings are about conditions the project
#: handles.  ``trimesh.sample``: "only got n/N samples!" of even surface sampling, once per lift env and object, which
#: the lift env's object clouds top up to their size (``components/execution/clouds.py``).
QUIET_LOGGERS = ("trimesh.sample",)


def quiet_handled_warnings() -> None:
    """Hold :data:`QUIET_LOGGERS` to errors (the CLI's process and the evaluation's worker processes)."""
    for name in QUIET_LOGGERS:
        logging.getLogger(name).setLevel(logging.ERROR)
