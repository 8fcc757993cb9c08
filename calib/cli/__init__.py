"""Stage 9, the command line: ``calib`` (:mod:`calib.cli.app`) and the options ``rig`` shares with it.

Each sub-command lives in its own module with a ``register(app)`` function; :mod:`calib.cli.app`
assembles them. The command line is thin: it parses, calls one function of the stages below and
prints. Importing this package imports nothing else, so ``rig`` can share :mod:`calib.cli.options`
without loading every ``calib`` command.
"""
