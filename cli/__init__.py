"""Thin typer glue: parse, load, call core, write, map errors to exit codes."""
