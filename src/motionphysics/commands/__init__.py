"""Subcommands of the ``motionphysics`` command line; see ``motionphysics.cli``."""
