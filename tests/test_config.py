import subprocess
import sys
from pathlib import Path

import pytest

from courtloc.common.config_loader import ConfigError
from courtloc.services.deployment import DeploymentConfig, load_deployment


def test_builtin_default_is_valid() -> None:
    config = load_deployment(None)
    assert isinstance(config, DeploymentConfig)
    assert config.zenoh.multicast_scouting is False


def test_wrong_type_names_file_field_and_value(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text('robot_id = "r1"\n[camera]\nfps = "fast"\n')
    with pytest.raises(ConfigError) as info:
        load_deployment(path)
    text = str(info.value)
    assert str(path) in text and "camera.fps" in text and "'fast'" in text


def test_unknown_field_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "typo.toml"
    path.write_text("[camera]\nfsp = 30\n")
    with pytest.raises(ConfigError, match="camera.fsp"):
        load_deployment(path)


def test_bad_robot_id_and_unknown_service(tmp_path: Path) -> None:
    path = tmp_path / "ids.toml"
    path.write_text('robot_id = "a/b"\n[launcher]\nservices = ["camera", "teleporter"]\n')
    with pytest.raises(ConfigError) as info:
        load_deployment(path)
    assert "robot_id" in str(info.value) and "launcher.services" in str(info.value)


def test_health_period_is_positive_and_named_when_not(tmp_path: Path) -> None:
    path = tmp_path / "health.toml"
    path.write_text("health_period_s = 0.25\n")
    assert load_deployment(path).health_period_s == 0.25
    assert load_deployment(None).health_period_s == 1.0
    path.write_text("health_period_s = 0\n")
    with pytest.raises(ConfigError, match="health_period_s"):
        load_deployment(path)


def test_folder_source_needs_its_section(tmp_path: Path) -> None:
    path = tmp_path / "folder.toml"
    path.write_text('[camera]\nsource = "folder"\n')
    with pytest.raises(ConfigError, match=r"\[camera.folder\]"):
        load_deployment(path)


def test_invalid_toml_is_reported(tmp_path: Path) -> None:
    path = tmp_path / "broken.toml"
    path.write_text("[camera\n")
    with pytest.raises(ConfigError, match="not valid"):
        load_deployment(path)


def test_example_configs_are_valid() -> None:
    folder = Path(__file__).resolve().parents[1] / "deploy" / "configs"
    examples = sorted(folder.glob("*.toml"))
    assert examples, "example configs ship in deploy/configs"
    for path in examples:
        load_deployment(path)


def test_stage_exits_nonzero_before_touching_the_bus(tmp_path: Path) -> None:
    """A bad config fails at start: no router is running, yet the process exits at once with the field."""
    path = tmp_path / "bad.toml"
    path.write_text("[zenoh]\nmode = \"satellite\"\n")
    result = subprocess.run([sys.executable, "-m", "courtloc", "run", "camera", "--config", str(path)],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert "zenoh.mode" in result.stderr and "satellite" in result.stderr


def test_relative_paths_are_relative_to_the_file(tmp_path: Path) -> None:
    folder = tmp_path / "site"
    folder.mkdir()
    path = folder / "robot.toml"
    path.write_text('[camera]\nsource = "folder"\n[camera.folder]\npath = "frames"\n[infer]\nstore = "store"\n')
    config = load_deployment(path)
    assert config.camera.folder is not None and config.camera.folder.path == folder / "frames"
    assert config.infer.store == folder / "store"
