"""The ``rsmt`` command: one sub-module per command group, each registering its sub-commands."""
