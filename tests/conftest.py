"""Test-wide settings."""

import os

# The command line keeps compiled programs on disk between runs; tests must not
# depend on (or fill) a user's cache, so it is off here.  tests/test_cli.py turns
# it on explicitly where it is tested.
os.environ["JAXPOSE_CACHE_DIR"] = "0"
