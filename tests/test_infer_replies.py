"""Model-control replies say what went wrong, never where the robot keeps its files."""
from __future__ import annotations

from pathlib import Path

import pytest
from buskit import BusClient, free_port, start_router, start_stage, write_config

from courtloc.common.control import Rollback
from courtloc.model_client import ModelClient
from courtloc.services.infer.store import ACTIVE_FILE

pytestmark = pytest.mark.integration


def test_a_store_error_reply_does_not_name_the_store_folder(tmp_path: Path) -> None:
    from infer_models import bundled_default

    if bundled_default() is None:
        pytest.skip("no bundled model")
    store = tmp_path / "store"
    port = free_port()
    router = start_router(port)
    config = write_config(tmp_path / "deploy.toml", port, f'[infer]\nstore = "{store}"\n')
    client = BusClient(port)
    stage = start_stage("infer", config)
    try:
        stage.wait_line("infer running for robot", timeout=60)
        # The store's own record (ACTIVE_FILE, not the legacy active.json a running store never reads again),
        # broken on disk: reading it fails with an error that names its full path.
        (store / ACTIVE_FILE).write_text("{ damaged")
        # The pit's client: it waits until the router knows the stage's queryable (which can come after the
        # stage says it runs: a one-shot query then reaches nobody), then asks once.
        reply = ModelClient(client.session, "robot1").request(Rollback(), timeout_s=30)
    finally:
        client.close()
        stage.stop()
        router.stop()
    assert not reply.ok and "is damaged" in reply.reason, reply.reason  # the error that names a path
    assert "<store>" in reply.reason, reply.reason
    assert str(tmp_path) not in reply.reason and str(tmp_path.resolve()) not in reply.reason, reply.reason
