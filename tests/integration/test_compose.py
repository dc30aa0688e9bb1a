"""docker-compose.yml (and its TLS override docker-compose.tls.yml): valid against the compose
specification, and its services, started locally with the files' own commands, environment and
mounts, reach each other and localize.

No Docker engine runs here, so the zenohd router is stood in for: by the test's hub session (a
peer that routes for clients) for the plain file, and by ``locnerf run router`` on the router's
own TLS and access-control file for the override, at the endpoint the files name with its host
replaced; the override's certificate mounts point at certificates made by ``locnerf certs``.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import zenoh
from ruamel.yaml import YAML

from locnerf_cli.certs import make_certificates
from locnerf_services.transport import TransportConfig
from locnerf_services.transport.router import Router, router_config
from tests.integration.conftest import REPO, Observer, Stack, wait_for, watch
from tests.integration.routing import PLAIN, SECURE, open_client, start_router, tls_for
from tests.services.helpers import free_port

COMPOSE = REPO / "docker-compose.yml"
COMPOSE_TLS = REPO / "docker-compose.tls.yml"
SERVICES = ("worker", "filter", "ingest")
ROUTER_HOST = "zenohd"


@pytest.mark.parametrize("path", [COMPOSE, COMPOSE_TLS], ids=["compose", "tls-override"])
def test_compose_file_is_valid_against_the_compose_specification(path):
    checker = Path(sys.executable).with_name("check-jsonschema")
    result = subprocess.run([str(checker), "--builtin-schema", "vendor.compose-spec", str(path)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr


def merged_services(*paths: Path) -> dict[str, dict]:
    """The services of compose files merged as ``docker compose -f a -f b`` does for the fields used
    here: environment by variable, volumes by container path, anything else replaced."""
    merged: dict[str, dict] = {}
    for path in paths:
        for name, service in YAML(typ="safe").load(path.read_text())["services"].items():
            current = merged.setdefault(name, {})
            for field, value in service.items():
                if field == "environment":
                    current[field] = current.get(field, {}) | value
                elif field == "volumes":
                    by_target = {volume.split(":")[1]: volume for volume in current.get(field, [])}
                    current[field] = list((by_target | {volume.split(":")[1]: volume for volume in value}).values())
                else:
                    current[field] = value
    return merged


def _local_path(container_path: str, mounts: dict[str, Path]) -> str:
    for target, source in mounts.items():
        if container_path == target:
            return str(source)
        if container_path.startswith(target + "/"):
            return str(source / container_path[len(target) + 1 :])
    return container_path


def start_compose_services(stack: Stack, services: dict[str, dict], endpoint: str, tmp_path: Path, certs: Path | None = None) -> Path:
    """Start worker, filter and ingest with the files' commands, environment and mounts (the router
    host replaced by ``endpoint``'s, ``./deploy/certs`` by ``certs``); returns the state folder."""
    state_dir = tmp_path / "state"
    state_dir.mkdir()
    for name in SERVICES:
        service = services[name]
        mounts: dict[str, Path] = {}
        for volume in service["volumes"]:
            source, target = volume.split(":")[:2]
            if source.startswith("./deploy/certs/"):
                mounts[target] = certs / source.removeprefix("./deploy/certs/")
            else:
                mounts[target] = (REPO / source).resolve() if source.startswith(".") else state_dir
        # The state file path in the config points into a named volume: copy the config with it mapped.
        arguments = [_local_path(a, mounts) for a in service["command"][1:]]
        config_index = arguments.index("--config") + 1
        config_copy = tmp_path / f"{name}.toml"
        shutil.copy(arguments[config_index], config_copy)
        config_copy.write_text(config_copy.read_text().replace("/var/lib/locnerf", str(state_dir)).replace('robot_id = "robot"', 'robot_id = "itest"'))
        arguments[config_index] = str(config_copy)
        environment = dict(stack.environment)
        for key, value in service["environment"].items():
            environment[key] = _local_path(value.replace(f"{ROUTER_HOST}:7447", endpoint.split("/", 1)[1]), mounts)
        assert service["command"][0] == "locnerf" and environment["LOCNERF_ZENOH_MODE"] == "client"
        assert environment["LOCNERF_ZENOH_CONNECT"] == endpoint
        stack.start(name, *arguments, environment=environment)
    return state_dir


def wait_for_localization(stack: Stack, observer: Observer, state_dir: Path) -> None:
    wait_for(lambda: observer.counter("updates_merged") >= 3 and len(observer.poses) >= 15, 180, "poses and merged updates", stack)
    assert (state_dir / "filter_state.json").is_file()


def test_compose_services_start_locally_and_reach_each_other(hub, tmp_path):
    stack, observer, _ = hub
    services = merged_services(COMPOSE)
    assert ROUTER_HOST in services
    state_dir = start_compose_services(stack, services, stack.endpoint, tmp_path)
    wait_for_localization(stack, observer, state_dir)


def test_compose_tls_override_services_reach_each_other_through_the_secure_router(hub, tmp_path):
    stack, _, _ = hub
    services = merged_services(COMPOSE, COMPOSE_TLS)
    assert services[ROUTER_HOST]["command"] == ["-c", "/etc/zenoh/router-tls.json5"]
    # zenohd finds the files its configuration names where the override mounts them.
    router_files = zenoh.Config.from_file(str(SECURE))
    mounted = {volume.split(":")[1] for volume in services[ROUTER_HOST]["volumes"]}
    for name in ("root_ca_certificate", "listen_certificate", "listen_private_key"):
        assert json.loads(router_files.get_json(f"transport/link/tls/{name}")) in mounted, name
    certs = tmp_path / "certs"
    make_certificates(certs)
    endpoint = f"tls/127.0.0.1:{free_port()}"
    start_router(stack, "router", endpoint, certs)
    robot = open_client(endpoint, tls_for(certs, "robot"))
    try:
        observer = watch(robot)
        state_dir = start_compose_services(stack, services, endpoint, tmp_path, certs)
        wait_for_localization(stack, observer, state_dir)
    finally:
        robot.close()


def test_ros2_override_is_valid_and_runs_the_filter_with_ros2_and_no_synthetic_ingest():
    from locnerf_services.filter_loop.__main__ import FilterProcessConfig
    from locnerf_services.runtime import load_service_config
    from locnerf_services.sensor_ingest.__main__ import IngestConfig

    override = REPO / "deploy/compose.ros2.yml"
    checker = Path(sys.executable).with_name("check-jsonschema")
    result = subprocess.run([str(checker), "--builtin-schema", "vendor.compose-spec", str(override)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    services = YAML(typ="safe").load(override.read_text())["services"]
    assert services["ingest"]["profiles"] == ["synthetic"]
    command = services["filter"]["command"]
    config_path = REPO / "deploy/config" / Path(command[command.index("--config") + 1]).name
    config = load_service_config(FilterProcessConfig, config_path, {})
    assert config.ros2.enabled and config.ros2.sensors and config.ros2.pose_topic == "amcl_pose"
    relay = load_service_config(IngestConfig, REPO / "deploy/config/ingest_ros2.toml", {})
    assert relay.source == "ros2" and relay.ros2.odometry_topic == "odom"


LOCNERF_SERVICES = (*SERVICES, "worker-cuda")


def test_one_service_builds_each_locnerf_image_and_the_others_run_it():
    services = YAML(typ="safe").load(COMPOSE.read_text())["services"]
    version = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["version"]
    builders = {services[name]["image"]: name for name in LOCNERF_SERVICES if "build" in services[name]}
    assert builders == {f"locnerf:{version}": "worker", f"locnerf:{version}-cuda": "worker-cuda"}
    assert sum("build" in service for service in services.values()) == len(builders), "one build entry per image"
    for name in LOCNERF_SERVICES:
        # Never pulled (a registry's "locnerf" is someone else's): built by its builder when missing.
        assert services[name]["image"] in builders and services[name]["pull_policy"] == "never", name
        assert services[builders[services[name]["image"]]]["build"]["dockerfile"] == "deploy/docker/Dockerfile"


def test_services_wait_for_a_healthy_router_retry_it_and_restart_after_a_failure():
    services = merged_services(COMPOSE)
    assert services[ROUTER_HOST]["restart"] == "unless-stopped" and services[ROUTER_HOST]["healthcheck"]["test"][0] == "CMD-SHELL"
    for name in LOCNERF_SERVICES:
        assert services[name]["depends_on"] == {ROUTER_HOST: {"condition": "service_healthy"}}, name
        assert TransportConfig().with_environment(services[name]["environment"]).connect_retry >= 60, name
    assert {name: services[name]["restart"] for name in SERVICES} == {"worker": "unless-stopped", "filter": "unless-stopped", "ingest": "on-failure"}


def test_the_router_healthcheck_passes_once_the_router_listens_and_fails_before():
    check = merged_services(COMPOSE)[ROUTER_HOST]["healthcheck"]["test"][1]
    assert "7447" in check
    port = free_port()
    local_check = ["sh", "-c", check.replace("7447", str(port))]
    assert subprocess.run(local_check, timeout=30).returncode != 0
    router = Router(router_config(PLAIN, [("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))]))
    try:
        assert subprocess.run(local_check, timeout=30).returncode == 0
    finally:
        router.close()


def test_the_image_is_multi_stage_without_system_packages_and_its_context_holds_only_the_sources():
    dockerfile = (REPO / "deploy/docker/Dockerfile").read_text()
    stages = re.findall(r"^FROM (\S+) AS (\S+)$", dockerfile, flags=re.MULTILINE)
    assert [image for image, _ in stages] == ["python:3.11-slim"] * 3 and stages[-1][1] == "runtime"
    runtime = dockerfile.split("AS runtime", 1)[1]
    assert "RUN " not in runtime, "the runtime stage only copies the environment built in the others"
    assert re.findall(r"^COPY --from=(\S+) /opt/locnerf /opt/locnerf$", runtime, flags=re.MULTILINE) == ["deps", "project"]
    assert "apt-get" not in dockerfile and "libgl" not in dockerfile
    copied = {path for line in dockerfile.splitlines() if line.startswith("COPY ") and "--from" not in line for path in line.split()[1:-1]}
    kept = {line[1:] for line in (REPO / ".dockerignore").read_text().splitlines() if line.startswith("!")}
    assert {Path(path).name for path in copied} == kept == {"pyproject.toml", "README.md", "locnerf", "services", "cli"}
    assert "*" in (REPO / ".dockerignore").read_text().splitlines(), "the context starts from nothing"
