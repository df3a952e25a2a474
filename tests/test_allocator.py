"""flows.runtime.apply_allocator: glibc's malloc settings for the process and the workers it starts."""

import platform
import subprocess
import sys

import pytest
from pydantic import ValidationError

from flows.config import RunConfig
from flows.runtime import apply_allocator

glibc = pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mallopt is glibc's")
NAMES = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")


@pytest.fixture
def clean_env(monkeypatch):
    """No MALLOC_*_ variable during the test; afterwards the environment as before (apply_allocator writes os.environ
    itself: setting each variable through monkeypatch first makes it restore them)."""
    for name in NAMES:
        monkeypatch.setenv(name, "0")
        monkeypatch.delenv(name)
    return monkeypatch


@glibc
def test_defaults_are_applied_in_bytes_and_exported_to_worker_processes(clean_env):
    applied = apply_allocator(RunConfig())
    assert applied == {"MALLOC_MMAP_THRESHOLD_": 32 * 2**20, "MALLOC_TRIM_THRESHOLD_": 1024 * 2**20}
    child = subprocess.run([sys.executable, "-c", "import os; print(os.environ['MALLOC_TRIM_THRESHOLD_'])"],
                           capture_output=True, text=True, check=True)
    assert child.stdout.strip() == str(1024 * 2**20)


@glibc
def test_zero_and_a_users_own_variable_leave_the_setting_alone(clean_env):
    clean_env.setenv("MALLOC_TRIM_THRESHOLD_", "12345")
    applied = apply_allocator(RunConfig(malloc_mmap_threshold_mb=0))
    assert applied == {}
    import os

    assert os.environ["MALLOC_TRIM_THRESHOLD_"] == "12345" and "MALLOC_MMAP_THRESHOLD_" not in os.environ


def test_an_mmap_threshold_above_glibcs_largest_is_a_config_error():
    with pytest.raises(ValidationError, match="malloc_mmap_threshold_mb"):
        RunConfig(malloc_mmap_threshold_mb=64)
