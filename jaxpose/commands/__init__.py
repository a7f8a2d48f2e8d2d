"""Subcommands of the `jaxpose` command line; each module exports `register(subparsers)`."""
