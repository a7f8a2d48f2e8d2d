"""The experiments' tests: the scripts of experiments/ import as top-level modules (as
they do when run as scripts), and so does tests/oracles.py."""

import os
import sys

TESTS = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ROOT = os.path.dirname(TESTS)
for _p in (os.path.join(ROOT, "experiments"), TESTS):
    if _p not in sys.path:
        sys.path.insert(0, _p)
