"""The router's access-control list follows the services table (no hand-written key in it)."""
from __future__ import annotations

import json

import zenoh

from courtloc.common.security import MONITOR_IDENTITY, PIT_IDENTITY, principal
from courtloc.common.services_table import (
    CONTROLS,
    HEALTH_TOPICS,
    SERVICES,
    TOPICS,
    liveliness_key,
    robot_wildcard_key,
)
from courtloc.security.acl import access_control, grants_for, identities

ROBOT = "robot7"


def _keys(identity: str, message: str, flow: str) -> set[str]:
    return set(grants_for(identity, ROBOT).allowed.get((message, flow), []))


def test_each_stage_publishes_exactly_its_outputs_and_health() -> None:
    for name, spec in SERVICES.items():
        expected = {TOPICS[p].key(ROBOT) for p in spec.outputs} | {HEALTH_TOPICS[name].key(ROBOT)}
        assert _keys(name, "put", "ingress") == expected
        assert _keys(name, "liveliness_token", "ingress") == {liveliness_key(ROBOT, name)}


def test_each_stage_reads_exactly_its_inputs() -> None:
    for name, spec in SERVICES.items():
        inputs = {TOPICS[p].key(ROBOT) for p in spec.inputs}
        assert _keys(name, "declare_subscriber", "ingress") == inputs
        assert _keys(name, "put", "egress") == inputs


def test_only_callers_query_controls_and_only_owners_answer() -> None:
    assert CONTROLS, "the table declares model control"
    for control in CONTROLS.values():
        key = control.key(ROBOT)
        for identity in identities():
            assert (key in _keys(identity, "query", "ingress")) == (identity in control.callers)
            assert (key in _keys(identity, "declare_queryable", "ingress")) == (identity == control.service)
    assert all(PIT_IDENTITY in c.callers for c in CONTROLS.values())


def test_monitor_reads_but_never_writes() -> None:
    ingress = {message for (message, flow) in grants_for(MONITOR_IDENTITY, ROBOT).allowed if flow == "ingress"}
    assert ingress == {"declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"}
    assert _keys(MONITOR_IDENTITY, "declare_subscriber", "ingress") == {robot_wildcard_key(ROBOT)}


def test_acl_is_default_deny_and_accepted_by_zenoh() -> None:
    acl = access_control(ROBOT)
    assert acl["enabled"] and acl["default_permission"] == "deny"
    assert {s["id"] for s in acl["subjects"]} == {principal(ROBOT, i) for i in identities()}
    rule_ids = {r["id"] for r in acl["rules"]}
    assert all(set(p["rules"]) <= rule_ids for p in acl["policies"])
    zenoh.Config().insert_json5("access_control", json.dumps(acl))  # raises on a schema error
