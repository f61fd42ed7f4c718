"""Queue workers running prtcore bakes: ``main.py`` (``prtcore worker``: consumer + lease
reaper), ``runner.py`` (one attempt: claim, heartbeat, outcome), ``bake_child.py`` (the bake
process itself), ``cli.py`` (the ``worker`` subcommand, registered with the ``prtcore``
command through the ``prtcore.commands`` entry-point group).

Built on :mod:`jobs` (settings, job store, artifacts, queue producer, reaper); never imports
:mod:`service`, and :mod:`prtcore` only through its public names."""
