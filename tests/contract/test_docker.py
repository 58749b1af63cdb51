"""Docker does not run on our machines: check ``docker/`` by parsing it."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path
from typing import Any

import pytest
import yaml

from eigenscope.cli import build_parser

ROOT = Path(__file__).resolve().parents[2]
DOCKER = ROOT / "docker"


@pytest.fixture(scope="module")
def compose() -> dict[str, Any]:
    doc: dict[str, Any] = yaml.safe_load((DOCKER / "compose.yaml").read_text())
    return doc


def assert_eigenscope_command(command: list[str]) -> None:
    assert command[0] == "eigenscope", command
    args = build_parser().parse_args(command[1:])  # exits (fails the test) on unknown options
    assert callable(args.handler)


def test_compose_services(compose: dict[str, Any]) -> None:
    services = compose["services"]
    assert {"redis", "api", "worker", "flower"} <= set(services)
    redis = services["redis"]
    command = redis["command"]
    # The persistence the Redis fault test runs with (see docker/README.md).
    assert command[command.index("--appendonly") + 1] == "yes"
    assert command[command.index("--appendfsync") + 1] == "always"
    assert any(v.endswith(":/data") for v in redis["volumes"])
    assert "redis-data" in compose["volumes"]
    assert "data" in compose["volumes"]
    for name in ("api", "worker"):
        service = services[name]
        assert service["build"]["dockerfile"] == "docker/Dockerfile"
        assert (DOCKER / service["build"]["context"] / service["build"]["dockerfile"]).resolve().is_file()
        env = service["environment"]
        assert env["EIGENSCOPE_REDIS_URL"].startswith("redis://redis:")
        assert "data:/data" in service["volumes"]
        assert_eigenscope_command(service["command"])
    assert services["api"]["command"][1] == "serve"
    assert "--no-worker" in services["api"]["command"]
    assert services["worker"]["command"][1] == "worker"
    assert services["worker"]["deploy"]["replicas"] >= 1
    assert "--broker=redis://redis:6379/0" in " ".join(services["flower"]["command"])


_VARIABLE = re.compile(r"\$\{(\w+)(?::-([^}]*))?\}")


def interpolate(value: Any, env: dict[str, str]) -> Any:
    """Compose's ``${VAR:-default}`` interpolation (``$$`` is a literal ``$``) over ``value``."""
    if isinstance(value, str):
        text = _VARIABLE.sub(lambda m: env.get(m.group(1)) or (m.group(2) or ""), value.replace("$$", "\0"))
        return text.replace("\0", "$")
    if isinstance(value, list):
        return [interpolate(v, env) for v in value]
    if isinstance(value, dict):
        return {k: interpolate(v, env) for k, v in value.items()}
    return value


def published_hosts(service: dict[str, Any], env: dict[str, str]) -> list[str]:
    """The host address of each published port (``HOST:PUBLISHED:TARGET``; none given is every one)."""
    hosts = []
    for mapping in interpolate(service.get("ports", []), env):
        parts = str(mapping).rsplit(":", 2)
        hosts.append(parts[0] if len(parts) == 3 else "0.0.0.0")
    return hosts


def api_settings(compose: dict[str, Any], env: dict[str, str]) -> Any:
    from backend.settings import Settings

    api_env = interpolate(compose["services"]["api"]["environment"], env)
    prefix = "EIGENSCOPE_"
    values = {k.removeprefix(prefix).lower(): v for k, v in api_env.items() if k.startswith(prefix)}
    return Settings(**{k: v for k, v in values.items() if k not in ("redis_url",)})


def test_compose_is_safe_by_default(compose: dict[str, Any]) -> None:
    """The API is published on loopback only unless asked; asked to publish it on a public address
    without keys, the API refuses to start; Flower runs only when enabled, behind basic auth, on
    loopback; no other service is published."""
    from eigenscope.cli import UsageError
    from eigenscope.commands.serve import check_exposure

    services = compose["services"]
    api = services["api"]
    host = api["command"][api["command"].index("--host") + 1]
    assert published_hosts(api, {}) == ["127.0.0.1"]
    settings = api_settings(compose, {})
    assert settings.api_keys is None
    check_exposure(host, settings, keys=False)  # open, but only this machine reaches it
    public = {"EIGENSCOPE_API_BIND": "0.0.0.0"}
    assert published_hosts(api, public) == ["0.0.0.0"]
    with pytest.raises(UsageError, match="without API keys"):
        check_exposure(host, api_settings(compose, public), keys=False)
    keyed = api_settings(compose, {**public, "EIGENSCOPE_API_KEYS": "k" * 32})
    assert keyed.api_keys == "k" * 32
    check_exposure(host, keyed, keys=True)
    # Only the API holds the keys (the workers need none).
    assert "EIGENSCOPE_API_KEYS" not in services["worker"]["environment"]
    # Flower: not started by default, refuses to start without basic auth, loopback only.
    flower = services["flower"]
    assert "flower" in flower.get("profiles", [])
    command = " ".join(interpolate(flower["command"], {}))
    assert 'test -n "$FLOWER_BASIC_AUTH" ||' in command
    assert '--basic-auth="$FLOWER_BASIC_AUTH"' in command
    assert published_hosts(flower, {}) == ["127.0.0.1"]
    for name, service in services.items():
        if name not in ("api", "flower"):
            assert "ports" not in service, name


def test_dockerfile() -> None:
    text = (DOCKER / "Dockerfile").read_text()
    stages = re.findall(r"^FROM\s+(\S+)", text, flags=re.M)
    assert len(stages) >= 2
    assert all(s == "python:3.11-slim" for s in stages)
    users = re.findall(r"^USER\s+(\S+)", text, flags=re.M)
    assert users
    assert users[-1] not in ("root", "0")
    for source in re.findall(r"^COPY\s+(?!--from)(\S+)\s", text, flags=re.M):
        if "[" not in source:
            assert (ROOT / source).exists(), source
    cmd = re.findall(r"^CMD\s+(\[.*\])", text, flags=re.M)[-1]
    assert_eigenscope_command(yaml.safe_load(cmd))
    for line in re.findall(r"^#\s+(?:API|worker):\s+(eigenscope .*)$", text, flags=re.M):
        assert_eigenscope_command(shlex.split(line))
    ignore = (DOCKER / "Dockerfile.dockerignore").read_text()
    assert ".venv" in ignore
    assert ".git" in ignore


def _exposed_metric_names(tmp_path: Path) -> set[str]:
    """Every sample name the API's and a worker's /metrics can show."""
    from prometheus_client import generate_latest

    from backend.store import Store
    from service.metrics import Metrics
    from workers.metrics import WorkerMetrics

    store = Store(f"sqlite:///{tmp_path / 'm.db'}")
    store.create_schema()
    try:
        text = Metrics(store).render().decode() + generate_latest(WorkerMetrics().registry).decode()
    finally:
        store.dispose()
    names: set[str] = set()
    for line in text.splitlines():
        if line.startswith("# TYPE "):
            _, _, name, kind = line.split()
            suffixes = {"histogram": ("_bucket", "_count", "_sum"), "counter": ("", "_total")}.get(
                kind, ("",)
            )
            names |= {name.removesuffix("_total") + suffix for suffix in suffixes}
            names.add(name)
    return names


def test_grafana_dashboard_shows_only_metrics_that_exist(tmp_path: Path) -> None:
    dashboard = json.loads((DOCKER / "grafana-dashboard.json").read_text())
    assert dashboard["__inputs"][0]["pluginId"] == "prometheus"
    exposed = _exposed_metric_names(tmp_path)
    used: set[str] = set()
    for panel in dashboard["panels"]:
        assert panel["datasource"]["uid"] == "${DS_PROMETHEUS}"
        for target in panel["targets"]:
            used |= set(re.findall(r"eigenscope_[a-z_]+", target["expr"]))
    assert used, "the dashboard queries nothing"
    assert used <= exposed, used - exposed
    wanted = {
        "eigenscope_job_duration_seconds_bucket",
        "eigenscope_job_queue_wait_seconds_bucket",
        "eigenscope_analysis_stage_seconds_bucket",
        "eigenscope_job_failures_total",
        "eigenscope_job_retries_total",
        "eigenscope_worker_busy",
        "eigenscope_worker_processes",
        "eigenscope_build_info",
    }
    assert wanted <= used, wanted - used


def test_workers_expose_their_own_metrics_in_compose(compose: dict[str, Any]) -> None:
    env = compose["services"]["worker"]["environment"]
    assert env["EIGENSCOPE_WORKER_METRICS_PORT"] == "9808"
    assert env["EIGENSCOPE_REDIS_URL"].startswith("redis://redis:")
