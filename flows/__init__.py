"""Prefect flows (one per stage + the pipeline), config loading and the CLI.

``tasks`` is imported first: it sets the project's Prefect environment defaults, which
Prefect reads once, when it is first imported.
"""

import tasks  # noqa: F401  (side effect: Prefect env defaults, before any `import prefect`)
