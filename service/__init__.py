"""prtcore HTTP front (FastAPI): bakes as jobs.

``main.py`` assembles the app, ``routers/`` holds one router per resource, ``uploads.py`` the
streaming, size-limited multipart intake, ``server.py`` ``prtcore serve`` (the API plus
supervised workers), ``cli.py`` the ``serve`` subcommand (entry-point group
``prtcore.commands``). Settings, the job store, artifacts and the queue come from
:mod:`jobs`. Bakes never run here and this package never imports :mod:`workers`: ``serve``
starts workers as processes (``python -m prtcore worker``).
"""
