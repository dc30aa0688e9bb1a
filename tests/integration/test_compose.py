"""docker-compose.yml: valid against the compose specification, and its services, started locally
with the file's own commands, environment and config mounts, reach each other and localize.

No Docker engine runs here, so the zenohd router is stood in for by the test's hub session (a
peer that routes for clients), at the endpoint the file names with its host replaced.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

from ruamel.yaml import YAML

from tests.integration.conftest import REPO, wait_for

COMPOSE = REPO / "docker-compose.yml"
SERVICES = ("worker", "filter", "ingest")


def test_compose_file_is_valid_against_the_compose_specification():
    checker = Path(sys.executable).with_name("check-jsonschema")
    result = subprocess.run(
        [str(checker), "--builtin-schema", "vendor.compose-spec", str(COMPOSE)], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stdout + result.stderr


def _local_path(container_path: str, mounts: dict[str, Path]) -> str:
    for target, source in mounts.items():
        if container_path.startswith(target + "/"):
            return str(source / container_path[len(target) + 1 :])
    return container_path


def test_compose_services_start_locally_and_reach_each_other(hub, tmp_path):
    stack, observer, _ = hub
    compose = YAML(typ="safe").load(COMPOSE.read_text())
    router_host = "zenohd"
    assert router_host in compose["services"]
    state_dir = tmp_path / "state"
    state_dir.mkdir()
    for name in SERVICES:
        service = compose["services"][name]
        mounts: dict[str, Path] = {}
        for volume in service["volumes"]:
            source, target = volume.split(":")[:2]
            mounts[target] = (REPO / source).resolve() if source.startswith(".") else state_dir
        # The state file path in the config points into a named volume: copy the config with it mapped.
        arguments = [_local_path(a, mounts) for a in service["command"][1:]]
        config_index = arguments.index("--config") + 1
        config_copy = tmp_path / f"{name}.toml"
        shutil.copy(arguments[config_index], config_copy)
        config_copy.write_text(config_copy.read_text().replace("/var/lib/locnerf", str(state_dir)).replace('robot_id = "robot"', 'robot_id = "itest"'))
        arguments[config_index] = str(config_copy)
        environment = dict(stack.environment)
        environment |= {k: v.replace(f"{router_host}:7447", stack.endpoint.removeprefix("tcp/")) for k, v in service["environment"].items()}
        assert service["command"][0] == "locnerf" and environment["LOCNERF_ZENOH_MODE"] == "client"
        stack.start(name, *arguments, environment=environment)
    wait_for(lambda: observer.counter("updates_merged") >= 3 and len(observer.poses) >= 15, 180, "poses and merged updates", stack)
    assert (state_dir / "filter_state.json").is_file()


def test_ros2_override_is_valid_and_runs_the_filter_with_ros2_and_no_synthetic_ingest():
    from services.filter_loop.__main__ import FilterProcessConfig
    from services.runtime import load_service_config
    from services.sensor_ingest.__main__ import IngestConfig

    override = REPO / "deploy/compose.ros2.yml"
    checker = Path(sys.executable).with_name("check-jsonschema")
    result = subprocess.run(
        [str(checker), "--builtin-schema", "vendor.compose-spec", str(override)], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stdout + result.stderr
    services = YAML(typ="safe").load(override.read_text())["services"]
    assert services["ingest"]["profiles"] == ["synthetic"]
    command = services["filter"]["command"]
    config_path = REPO / "deploy/config" / Path(command[command.index("--config") + 1]).name
    config = load_service_config(FilterProcessConfig, config_path, {})
    assert config.ros2.enabled and config.ros2.sensors and config.ros2.pose_topic == "amcl_pose"
    relay = load_service_config(IngestConfig, REPO / "deploy/config/ingest_ros2.toml", {})
    assert relay.source == "ros2" and relay.ros2.odometry_topic == "odom"
