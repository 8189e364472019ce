"""Subcommands of the ``solarnav`` CLI, one module each (see :mod:`app.cli`)."""
