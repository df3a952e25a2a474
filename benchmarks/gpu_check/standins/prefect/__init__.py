"""Stand-in for prefect on the GPU machine (its image has no prefect): the decorators return the function.
Only for the device checks of torch code; never installed by the project."""


def _decorator(fn=None, **_kwargs):
    if fn is None:
        return lambda f: f
    return fn


task = flow = _decorator


def get_run_logger():
    import logging
    return logging.getLogger("prefect-standin")
