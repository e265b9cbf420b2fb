"""The REST service: live cell status from the bus, scenarios, parameter sets, landing page.

- ``registry.CellRegistry``: subscribes to every cell's status, verdicts and params answers over
  zenoh; ``request_params`` sends a scenario to a worker and waits for its answer.
- ``app.create_app(registry, scenarios_folder, viewer_url=...)``: the FastAPI app.
- ``server.ApiServer(app, host, port)``: uvicorn in a thread; ``start() -> url``, ``stop()``.

Typical wiring (next to the viser dashboard, in one process)::

    registry = CellRegistry.connect(bus_port).start()
    server = ApiServer(create_app(registry, viewer_url=viewer_url), port=8000)
    print(server.start())
    ...
    server.stop(); registry.close()

Nothing here imports viser.
"""

from sara_app.api.app import create_app
from sara_app.api.registry import CellRegistry, ParamsAnswer
from sara_app.api.server import ApiServer, ApiServerError
from sara_app.errors import WorkerTimeoutError

__all__ = [
    "ApiServer",
    "ApiServerError",
    "CellRegistry",
    "ParamsAnswer",
    "WorkerTimeoutError",
    "create_app",
]
