"""Launch specs: the whole graph in one YAML file, and the check that refuses a graph that cannot work.

A spec names the router, the hosts, and every service with its host, its ``stereovox``
sub-command, the keys it reads (schema and queue policy) and writes (schema). ``{name}``
placeholders are filled from ``--var name=value`` so one file serves a test, a demo and a car.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from common.errors import ConfigError
from common.messages import SCHEMAS, Message

QUEUE_POLICIES = ("newest", "fifo")
RESTART_POLICIES = ("always", "on-failure", "never")
_PLACEHOLDER = re.compile(r"\{([a-z_][a-z0-9_]*)\}")


@dataclass
class ServiceSpec:
    name: str
    host: str
    command: list[str]
    inputs: dict[str, dict[str, str]] = field(default_factory=dict)  # key -> {schema, queue}
    outputs: dict[str, str] = field(default_factory=dict)  # key -> schema id
    restart: str = "on-failure"
    source: bool = False  # started last, once every other service is alive


@dataclass
class LaunchSpec:
    name: str
    vehicle: str
    router_host: str
    router_listen: str
    hosts: dict[str, dict[str, Any]]
    services: dict[str, ServiceSpec]
    path: Path | None = None

    def on_host(self, host: str | None) -> list[ServiceSpec]:
        return [s for s in self.services.values() if host is None or s.host == host]

    def router_endpoint(self) -> str:
        """Where clients connect: the router's listen endpoint (with a concrete address)."""
        return self.router_listen


def _fill(value: Any, variables: dict[str, str], missing: set[str]) -> Any:
    if isinstance(value, str):

        def sub(m: re.Match[str]) -> str:
            if m.group(1) in variables:
                return variables[m.group(1)]
            missing.add(m.group(1))
            return m.group(0)

        return _PLACEHOLDER.sub(sub, value)
    if isinstance(value, list):
        return [_fill(v, variables, missing) for v in value]
    if isinstance(value, dict):
        return {k: _fill(v, variables, missing) for k, v in value.items()}
    return value


def load_spec(path: str | Path, variables: dict[str, str] | None = None, strict: bool = True) -> LaunchSpec:
    """Read a spec and fill its placeholders; ``strict`` refuses placeholders left unfilled."""
    p = Path(path)
    try:
        raw = yaml.safe_load(p.read_text())
    except OSError as exc:
        raise ConfigError(f"cannot read launch spec {p}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{p}: not valid YAML: {exc}") from None
    if not isinstance(raw, dict):
        raise ConfigError(f"{p}: the top level must be a mapping")
    missing: set[str] = set()
    raw = _fill(raw, dict(variables or {}), missing)
    if strict and missing:
        raise ConfigError(f"{p}: placeholders without a value: {sorted(missing)} (pass --var NAME=VALUE)")
    try:
        services = {
            name: ServiceSpec(
                name=name,
                host=str(s["host"]),
                command=[str(c) for c in s["command"]],
                inputs={k: dict(v or {}) for k, v in (s.get("inputs") or {}).items()},
                outputs={k: str(v) for k, v in (s.get("outputs") or {}).items()},
                restart=str(s.get("restart", "on-failure")),
                source=bool(s.get("source", False)),
            )
            for name, s in (raw.get("services") or {}).items()
        }
        router = raw.get("router") or {}
        return LaunchSpec(
            name=str(raw.get("name", p.stem)),
            vehicle=str(raw.get("vehicle", "ego")),
            router_host=str(router.get("host", "")),
            router_listen=str(router.get("listen", "")),
            hosts={str(k): dict(v or {}) for k, v in (raw.get("hosts") or {}).items()},
            services=services,
            path=p,
        )
    except (KeyError, TypeError, AttributeError) as exc:
        raise ConfigError(f"{p}: malformed service or router entry ({type(exc).__name__}: {exc})") from None


def _schema_ok(schema_id: str) -> type[Message] | None:
    m = re.fullmatch(r"stereovox\.([A-Za-z]+)/(\d+)", schema_id)
    if not m or m.group(1) not in SCHEMAS:
        return None
    cls = SCHEMAS[m.group(1)]
    return cls if int(m.group(2)) == cls.VERSION else None


def check(spec: LaunchSpec) -> list[str]:
    """Every problem that would stop the graph from working; empty when it is consistent."""
    errors: list[str] = []
    if not spec.router_listen:
        errors.append("router: no listen endpoint")
    if spec.router_host not in spec.hosts:
        errors.append(f"router: host {spec.router_host!r} is not among hosts {sorted(spec.hosts)}")
    publishers: dict[str, list[tuple[str, str]]] = {}
    for svc in spec.services.values():
        if svc.host not in spec.hosts:
            errors.append(f"service {svc.name}: host {svc.host!r} is not among hosts {sorted(spec.hosts)}")
        if svc.restart not in RESTART_POLICIES:
            errors.append(f"service {svc.name}: restart {svc.restart!r} is not one of {RESTART_POLICIES}")
        if not svc.command:
            errors.append(f"service {svc.name}: empty command")
        for key, schema in svc.outputs.items():
            if _schema_ok(schema) is None:
                errors.append(f"service {svc.name}: output {key} has unknown schema or version {schema!r}")
            publishers.setdefault(key, []).append((svc.name, schema))
    for svc in spec.services.values():
        for key, opts in svc.inputs.items():
            queue = opts.get("queue", "newest")
            if queue not in QUEUE_POLICIES:
                errors.append(f"service {svc.name}: input {key} queue {queue!r} is not one of {QUEUE_POLICIES}")
            if "*" in key:
                continue  # a wildcard subscriber (the recorder) takes whatever is there
            pubs = publishers.get(key, [])
            if not pubs:
                errors.append(f"service {svc.name}: input {key} has no publisher")
            elif len(pubs) > 1:
                errors.append(f"service {svc.name}: input {key} has {len(pubs)} publishers: {[p[0] for p in pubs]}")
            else:
                pub_name, pub_schema = pubs[0]
                want = opts.get("schema")
                if want and want != pub_schema:
                    errors.append(
                        f"service {svc.name}: input {key} expects {want} but {pub_name} publishes {pub_schema}"
                    )
    return errors
