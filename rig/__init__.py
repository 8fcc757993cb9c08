"""Orchestration: configuration, plans, the runner, sessions and the command line."""
