"""Helpers shared by the tests: run the CLI, build small runs, compare states."""
