"""Queue workers running prtcore bakes (DESIGN 6): ``queue.py`` (the huey queue shared with
the API), ``main.py`` (``prtcore worker``: consumer + lease reaper), ``runner.py`` (one
attempt: claim, heartbeat, outcome), ``bake_child.py`` (the bake process itself)."""
