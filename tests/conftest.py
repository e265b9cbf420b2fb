"""Every test runs with its own data folder (``SARA_APP_DATA``): the audit log and the saved
cell states of the processes it starts never touch the user's, nor leak between test runs. The
in-process API client's host name is allowed (see ``sara_app.api.guard``)."""

from __future__ import annotations

import os
import tempfile

from sara_app.api import guard

_DATA = tempfile.mkdtemp(prefix="sara_app_test_data_")
os.environ["SARA_APP_DATA"] = _DATA
# FastAPI's TestClient sends "Host: testserver"; the service answers only to loopback names
guard.LOOPBACK_NAMES = (*guard.LOOPBACK_NAMES, "testserver")
