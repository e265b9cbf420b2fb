"""Every test runs with its own data folder (``SARA_APP_DATA``): the audit log and the saved
cell states of the processes it starts never touch the user's, nor leak between test runs."""

from __future__ import annotations

import os
import tempfile

_DATA = tempfile.mkdtemp(prefix="sara_app_test_data_")
os.environ["SARA_APP_DATA"] = _DATA
