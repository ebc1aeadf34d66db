"""CLI command families, one module each; every module exports ``COMMANDS``, a list of click commands."""
