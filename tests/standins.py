"""Stand-ins for optional dependencies that CI does not install (Ray: ``pip install 'multigrasp[ray]'``)."""

from __future__ import annotations

import concurrent.futures
import types


class FakeRay(types.ModuleType):
    """A stand-in for the ``ray`` module: records what is asked of it (``calls``) and runs each remote task at once,
    in this process, returning a finished ``concurrent.futures.Future`` as ``ObjectRef.future()`` does."""

    def __init__(self, initialized: bool = False):
        super().__init__("ray")
        self.initialized, self.calls = initialized, []

    def is_initialized(self):
        return self.initialized

    def init(self, **kwargs):
        self.calls.append(("init", kwargs))
        self.initialized = True

    def shutdown(self):
        self.calls.append(("shutdown", {}))
        self.initialized = False

    def remote(self, **options):
        ray = self

        class Remote:
            def __init__(self, fn):
                self.fn = fn

            def remote(self, *args):
                ray.calls.append(("task", options))
                future = concurrent.futures.Future()
                try:
                    future.set_result(self.fn(*args))
                except BaseException as exc:  # as a Ray task's error reaches its caller
                    future.set_exception(exc)
                return types.SimpleNamespace(future=lambda: future)
        return Remote

    def cancel(self, ref, force=False):
        self.calls.append(("cancel", {"force": force}))
