"""Command-line interface: the `locnerf` command and its subcommands."""
