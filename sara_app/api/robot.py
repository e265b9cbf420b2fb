"""REST routes of the operator's actions on the robot: confirm where a stopped robot stands so
that the worker plans from there (the contract's ``sara/<cell>/robot/replan``), every request
recorded in the audit log.

- ``POST /api/cells/{cell}/robot/replan`` (:class:`ReplanBody`): after the robot stopped or was
  moved away from the worker's plan while its controller kept running (a protective stop, hand
  guiding), the cell stays a tracking fault: the worker never moves its plan to where the
  controller says on the controller's word alone. The operator confirms the joint positions
  the controller reports (the refusal names them); 200 the worker plans from there, 409
  refused (the state is not fresh, not at rest, not within the tracking tolerance of ``q``, the
  worker's plan still brakes, or the robot stands where the plan is), 504 no answer; each
  audited under the request's user.
- ``GET /api/cells/{cell}/robot/audit``: the cell's recorded actions on the robot, newest first.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any

from fastapi import FastAPI, Query, Request
from pydantic import BaseModel, ConfigDict, Field

from sara_app.api.guard import request_user
from sara_app.api.people import audited_ask
from sara_app.api.registry import CellRegistry
from sara_app.api.schema import BODY_RESPONSES, CellName, responses
from sara_app.bus.messages import JointVector
from sara_app.ops.audit import AuditLog


class ReplanBody(BaseModel):
    """The joint positions the operator confirms (rad, the robot's joint order) and why."""

    model_config = ConfigDict(
        extra="forbid", strict=True, json_schema_extra={"examples": [{
            "q": [0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.79],
            "reason": "protective stop reset; the arm stands where the controller says"}]},
    )  # fmt: skip

    q: JointVector
    reason: Annotated[str, Field(min_length=1, max_length=500)]


def add_robot_routes(
    app: FastAPI,
    registry: CellRegistry,
    audit: Callable[[], AuditLog],
    known_cell: Callable[[str], dict[str, Any]],
    check_name: Callable[[str, str], str],
) -> None:
    """Add the re-plan route and its audit listing (``audit()`` gives the open log)."""

    @app.post(
        "/api/cells/{cell}/robot/replan", tags=["robot"],
        responses={**BODY_RESPONSES, **responses(
            404, 409, 422, 503, 504,
            _409="the worker refused: the robot is not at rest at the confirmed position, its "
            "state is not fresh, the plan still brakes, or there is nothing to re-plan")},
    )  # fmt: skip
    def replan(cell: CellName, body: ReplanBody, request: Request) -> dict[str, Any]:
        """Plan from where the robot stands (the position its controller reports, confirmed by
        the operator) after it stopped or was moved away from the plan; audited whatever the
        outcome."""
        known_cell(cell)
        user = request_user(request)
        entry = audited_ask(
            cell,
            lambda: registry.request_replan(cell, body.q, user, body.reason),
            lambda **outcome: audit().record_robot_action(
                cell=cell, q_rad=body.q, user=user, reason=body.reason, **outcome
            ),
        )
        return {"cell": cell, "replanned": True, "audit": entry}

    @app.get("/api/cells/{cell}/robot/audit", tags=["robot"], responses=responses(422, 503))
    def robot_audit(
        cell: CellName, limit: int = Query(50, ge=1, le=10_000)
    ) -> list[dict[str, Any]]:
        """The cell's operator actions on the robot, newest first."""
        check_name("cell", cell)
        return audit().robot_actions(cell, limit)
