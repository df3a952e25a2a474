"""User-facing errors.

Every problem caused by the user's input (a config value, an object name, a mesh
file, a corrupt cache file) is raised as :class:`MultigraspError` with a single
line that names the problem *and* the fix.  The CLI prints ``error: <message>``
and exits with status 2 instead of showing a traceback.
"""


class MultigraspError(Exception):
    """A problem with the user's input, reported as one line: what is wrong and how to fix it."""

    def __init__(self, message: str):
        one_line = " ".join(str(message).split())
        super().__init__(one_line)
