"""The bottom layer of the bake service, shared by the API (:mod:`service`) and the queue
workers (:mod:`workers`), which never import each other:

``config.py``    the settings (``PRT_*``, pydantic-settings)
``store.py``     the durable job table, the source of truth (SQLite or PostgreSQL)
``artifacts.py`` the on-disk layout of inputs and bundles
``queue.py``     the huey queue: producer API (enqueue, ping, depth); the consumer side
                 hands its task handler to :func:`jobs.queue.make_huey`
``reaper.py``    the lease reaper (workers and the ``serve`` supervisor both run it)
``lifeline.py``  process lifetime: a child dies with the process that supervises it

It imports the library only through ``prtcore``'s public names, and nothing above it.
"""
