"""prtcore HTTP front (FastAPI; DESIGN 6): bakes as jobs.

``main.py`` assembles the app, ``routers/`` holds one router per resource, ``config.py`` the
pydantic-settings configuration (``PRT_*``), ``store.py`` the durable job table (SQLite or
PostgreSQL), ``uploads.py`` the streaming, size-limited multipart intake, ``artifacts.py``
the on-disk layout of inputs and bundles. Bakes never run here: see :mod:`workers`.
"""
