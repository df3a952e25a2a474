"""Base class for every typed config section.

Sections are pydantic v2 models that are frozen (hashable, safe to share between
threads) and reject unknown keys, so a typo in a YAML profile or a ``--set``
override fails loudly instead of being ignored.
"""

from pydantic import BaseModel, ConfigDict


class Section(BaseModel):
    """A frozen, strict config section; each field carries a one-line description."""

    model_config = ConfigDict(frozen=True, extra="forbid", validate_default=True)
