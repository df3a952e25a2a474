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


#: The console's log line (``--verbose`` shows INFO lines, else warnings and errors).
LOG_FORMAT = "%(levelname)s %(name)s: %(message)s"


class RunNameFormatter(logging.Formatter):
    """:data:`LOG_FORMAT`, with the Prefect run a record comes from after the logger's name: Prefect's records carry
    it as ``task_run_name`` / ``flow_run_name``, which the plain format dropped, so ``--verbose`` printed "INFO
    prefect.task_runs: Finished in state Completed()" for every unit without saying which."""

    def __init__(self) -> None:
        super().__init__(LOG_FORMAT)

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        run = getattr(record, "task_run_name", None) or getattr(record, "flow_run_name", None)
        return text.replace(f"{record.name}: ", f"{record.name} ({run}): ", 1) if run else text


def configure_console_logging(verbose: bool) -> None:
    """The root logger's console handler for a command (no-op where the root already has handlers, as under
    pytest): INFO with ``verbose``, else WARNING, each line in :class:`RunNameFormatter`'s form."""
    if logging.getLogger().handlers:
        return
    handler = logging.StreamHandler()
    handler.setFormatter(RunNameFormatter())
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING, handlers=[handler])
