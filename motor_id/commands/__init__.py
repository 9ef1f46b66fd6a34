"""Subcommands of the `motor-id` CLI: thin wrappers around the core."""
