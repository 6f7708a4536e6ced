"""The trainer's tests import the installed package (`pip install
--no-build-isolation -e models`, which scripts/test.sh does); nothing here
edits sys.path."""
import importlib.util

import pytest

if importlib.util.find_spec("nedrt_train") is None:
    raise pytest.UsageError("nedrt_train is not installed: run `.venv/bin/pip install --no-build-isolation -e models` "
                            "(scripts/test.sh does)")
