import re
import subprocess
from pathlib import Path

import pytest

from courtloc.common.services_table import SERVICES, TOPICS, check_robot_id, liveliness_key, topic_of_key

REPO = Path(__file__).resolve().parents[1]


def test_every_key_follows_the_scheme() -> None:
    for topic in TOPICS.values():
        key = topic.key("robot1")
        assert re.fullmatch(r"courtloc/robot1/[a-z_]+/[a-z_]+", key), key
        assert topic_of_key(key) is topic


def test_services_inputs_and_outputs_are_topics_of_the_table() -> None:
    for spec in SERVICES.values():
        for path in (*spec.inputs, *spec.outputs):
            assert path in TOPICS
        for path in spec.outputs:
            assert TOPICS[path].service == spec.name, "a service publishes only its own topics"


def test_every_input_has_a_producer() -> None:
    produced = {p for s in SERVICES.values() for p in s.outputs}
    for spec in SERVICES.values():
        assert set(spec.inputs) <= produced


def test_qos_and_freshness_are_sane() -> None:
    for topic in TOPICS.values():
        assert topic.rate_hz > 0
        assert topic.freshness_ms >= 1000.0 / topic.rate_hz, f"{topic.path} would always be stale"
        if topic.rate_hz >= 10:
            assert topic.congestion == "drop", "streams must never block the publisher"


@pytest.mark.parametrize("bad", ["", "a/b", "robot*", "x" * 70, "-lead"])
def test_robot_id_must_be_one_key_chunk(bad: str) -> None:
    with pytest.raises(ValueError):
        check_robot_id(bad)
    with pytest.raises(ValueError):
        liveliness_key(bad, "camera")


def test_no_other_file_spells_a_key_expression() -> None:
    """Key expressions live in the services table only."""
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "*.py"], cwd=REPO,
                           capture_output=True, text=True, check=True).stdout.split()
    offenders = []
    for name in files:
        if name.endswith("services_table.py") or name.startswith("tests/"):
            continue
        text = (REPO / name).read_text(encoding="utf-8")
        if re.search(r"""["']courtloc/""", text):
            offenders.append(name)
    assert offenders == []
