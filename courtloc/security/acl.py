"""The robot router's access-control list, derived from the services table.

Default deny. Each stage may publish only its own outputs and health, declare only its own
liveliness token, and subscribe only its inputs. A control queryable (the infer model store) may be
answered only by its owning service and asked only by the table's `callers` (the pit). The monitor
identity (the launcher's status line on the robot) and the pit may read every key of the robot.

Zenoh checks each message against the rules of the session's subject on the way in (`ingress`,
from that session into the router) and out (`egress`, from the router to that session).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from courtloc.common.security import MONITOR_IDENTITY, PIT_IDENTITY, principal
from courtloc.common.services_table import (
    CONTROLS,
    HEALTH_TOPICS,
    SERVICES,
    TOPICS,
    all_liveliness_key,
    check_robot_id,
    liveliness_key,
    robot_wildcard_key,
)


@dataclass
class Grants:
    """What one identity may do: message kind -> flow -> key expressions."""

    identity: str
    allowed: dict[tuple[str, str], list[str]] = field(default_factory=dict)

    def allow(self, flow: str, messages: tuple[str, ...], keys: list[str]) -> None:
        for message in messages:
            bucket = self.allowed.setdefault((message, flow), [])
            bucket.extend(k for k in keys if k not in bucket)


def identities() -> list[str]:
    """Every identity `courtloc secure init` issues credentials for."""
    return [*SERVICES, MONITOR_IDENTITY, PIT_IDENTITY]


def _publish(grants: Grants, keys: list[str]) -> None:
    grants.allow("ingress", ("put",), keys)
    # The publisher must learn that subscribers exist, or its session filters the samples out.
    grants.allow("egress", ("declare_subscriber",), keys)


def _subscribe(grants: Grants, keys: list[str]) -> None:
    grants.allow("ingress", ("declare_subscriber",), keys)
    grants.allow("egress", ("put",), keys)


def _read_everything(grants: Grants, robot_id: str) -> None:
    _subscribe(grants, [robot_wildcard_key(robot_id)])
    alive = [all_liveliness_key(robot_id)]
    grants.allow("ingress", ("declare_liveliness_subscriber", "liveliness_query"), alive)
    grants.allow("egress", ("liveliness_token", "reply"), alive)


def grants_for(identity: str, robot_id: str) -> Grants:
    check_robot_id(robot_id)
    grants = Grants(identity)
    if identity in SERVICES:
        spec = SERVICES[identity]
        _publish(grants, [TOPICS[p].key(robot_id) for p in spec.outputs] + [HEALTH_TOPICS[identity].key(robot_id)])
        if spec.inputs:
            _subscribe(grants, [TOPICS[p].key(robot_id) for p in spec.inputs])
        grants.allow("ingress", ("liveliness_token",), [liveliness_key(robot_id, identity)])
    if identity in (MONITOR_IDENTITY, PIT_IDENTITY):
        _read_everything(grants, robot_id)
    for control in CONTROLS.values():
        key = [control.key(robot_id)]
        if control.service == identity:
            grants.allow("ingress", ("declare_queryable", "reply"), key)
            grants.allow("egress", ("query",), key)
        if identity in control.callers:
            grants.allow("ingress", ("query",), key)
            grants.allow("egress", ("reply", "declare_queryable"), key)
    return grants


def access_control(robot_id: str) -> dict[str, Any]:
    """The zenoh `access_control` section for the robot's router."""
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    for identity in identities():
        name = principal(robot_id, identity)
        # A session is this identity only when BOTH its certificate and its password say so.
        subjects.append({"id": name, "cert_common_names": [name], "usernames": [name]})
        rule_ids = []
        for (message, flow), keys in sorted(grants_for(identity, robot_id).allowed.items()):
            rule_id = f"{identity}.{flow}.{message}"
            rules.append({"id": rule_id, "permission": "allow", "flows": [flow], "messages": [message],
                          "key_exprs": keys})
            rule_ids.append(rule_id)
        policies.append({"id": name, "rules": rule_ids, "subjects": [name]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}
