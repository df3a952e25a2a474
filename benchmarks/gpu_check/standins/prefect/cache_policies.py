class CachePolicy:  # stand-in (see prefect/__init__.py)
    pass


NO_CACHE = CachePolicy()
