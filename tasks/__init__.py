"""Prefect tasks: thin glue that loads inputs, calls components, writes artifacts + manifests.

Importing this package sets the project's Prefect defaults (before Prefect itself is
imported anywhere); values already in the environment win.
"""

import os

PREFECT_ENV_DEFAULTS = {
    "PREFECT_SERVER_ANALYTICS_ENABLED": "false",  # no telemetry from the project
    "PREFECT_LOGGING_LEVEL": "WARNING",           # the CLI prints its own progress lines
    "PREFECT_RESULTS_PERSIST_BY_DEFAULT": "true",
    "PREFECT_UI_ENABLED": "false",
    # Prefect's default (20 s) for its temporary local API server to start was too short on a busy 2-core machine:
    # beside a synthesis run, `multigrasp run` stopped with "Timed out while attempting to connect to ephemeral
    # Prefect API server" (thirty-fifth session).
    "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS": "120",
}

for _name, _value in PREFECT_ENV_DEFAULTS.items():
    os.environ.setdefault(_name, _value)
