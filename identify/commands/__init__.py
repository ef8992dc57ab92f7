"""The subcommands of ``python -m identify``: one module per command group, each with
``add_parser(sub)`` (its arguments) and the ``cmd_*`` functions it sets as ``func`` (parsing the
arguments into a :class:`~identify.pipeline.Job` or a call of the library, and printing). The work
itself lives in :mod:`identify.pipeline` and below; libraries load only when a command runs, so
``--help`` answers at once. :data:`identify.cli.COMMANDS` lists the modules in help order.
"""
