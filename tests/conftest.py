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

# The recordings beside the repository (../shared/data), for the tests that use recordings the
# package does not ship; the package itself looks only at SARA_DATA_DIR.
_SHARED = os.path.join(os.path.dirname(__file__), "..", "..", "shared")
if "SARA_DATA_DIR" not in os.environ and os.path.isdir(os.path.join(_SHARED, "data", "cmu_mocap")):
    os.environ["SARA_DATA_DIR"] = os.path.abspath(_SHARED)
