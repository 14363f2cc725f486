"""Launch specs: the whole graph in one YAML file, and the check that refuses a graph that cannot work.

A spec names the router, the hosts with their addresses, the Zenoh configuration files, and
every service with its host, its ``stereovox`` sub-command, the keys it reads (schema and queue
policy) and writes (schema). ``{name}`` placeholders are filled from ``--var name=value`` so one
file serves a test, a demo and a car. :func:`check` finds what would only show up at run time on
the car: a key nobody publishes, two publishers, a schema version one side does not speak, a
router listening on an address that is not its computer's.
"""

from __future__ import annotations

import ipaddress
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from common.errors import ConfigError, StereovoxError
from common.messages import SCHEMAS, Message

QUEUE_POLICIES = ("newest", "fifo")
RESTART_POLICIES = ("always", "on-failure", "never")
ZENOH_ROLES = ("router", "client", "peer")
WILDCARD_HOSTS = ("0.0.0.0", "::")
_PLACEHOLDER = re.compile(r"\{([a-z_][a-z0-9_]*)\}")
_ENDPOINT = re.compile(r"(?:tcp|tls|quic)/\[?([^\]]+?)\]?:(\d+)")


@dataclass
class ServiceSpec:
    name: str
    host: str
    command: list[str]
    inputs: dict[str, dict[str, str]] = field(default_factory=dict)  # key -> {schema, queue}
    outputs: dict[str, str] = field(default_factory=dict)  # key -> schema id
    restart: str = "on-failure"
    source: bool = False  # started last, once every other service is alive

    def queue_policy(self) -> str | None:
        """The one input policy ``stereovox run`` takes; None when the inputs disagree or there are none."""
        policies = {opts.get("queue", "newest") for opts in self.inputs.values()}
        return policies.pop() if len(policies) == 1 else None


@dataclass
class LaunchSpec:
    name: str
    vehicle: str
    router_host: str
    router_listen: str
    hosts: dict[str, dict[str, Any]]
    services: dict[str, ServiceSpec]
    path: Path | None = None
    zenoh: dict[str, Path] = field(default_factory=dict)  # role -> JSON5 file
    unfilled: set[str] = field(default_factory=set)  # placeholders left (only when not strict)

    def on_host(self, host: str | None) -> list[ServiceSpec]:
        return [s for s in self.services.values() if host is None or s.host == host]

    def router_endpoint(self) -> str:
        """Where clients connect: the listen endpoint, a wildcard address replaced by the router host's."""
        host, port = endpoint_address(self.router_listen)
        if host in WILDCARD_HOSTS:
            host = str(self.hosts.get(self.router_host, {}).get("address", "127.0.0.1"))
        proto = self.router_listen.split("/", 1)[0]
        return f"{proto}/{'[' + host + ']' if ':' in host else host}:{port}"


def endpoint_address(endpoint: str) -> tuple[str, int]:
    """``tcp/127.0.0.1:7447`` -> ("127.0.0.1", 7447)."""
    match = _ENDPOINT.fullmatch(endpoint)
    if not match:
        raise ConfigError(f"router endpoint {endpoint!r} is not tcp/HOST:PORT (or tls/, quic/)")
    return match.group(1), int(match.group(2))


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


def _read_mapping(p: Path) -> dict[str, Any]:
    """A spec file's YAML, which must be a mapping; anything else names the file."""
    try:
        raw = yaml.safe_load(p.read_text())
    except OSError as exc:
        raise ConfigError(f"cannot read launch spec {p}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{p}: not valid YAML: {exc}") from None
    if not isinstance(raw, dict):
        raise ConfigError(f"{p}: the top level must be a mapping")
    return raw


def _extended(raw: dict[str, Any], path: Path, depth: int = 0) -> dict[str, Any]:
    """A spec with ``extends: OTHER.yaml`` is that spec with its own mappings merged over it, key by
    key (lists, such as a command, are replaced whole): a variant names only what it changes."""
    base_name = raw.pop("extends", None)
    if base_name is None:
        return raw
    base_path = path.parent / str(base_name)
    if depth >= 4:
        raise ConfigError(f"{path}: extends {base_name}: more than 4 levels of extends")
    try:
        base = _read_mapping(base_path)
    except ConfigError as exc:
        raise ConfigError(f"{path}: extends {base_name}: {exc}") from None
    base = _extended(base, base_path, depth + 1)
    # the base's Zenoh files are beside the base, wherever the variant is
    base["zenoh"] = {role: str((base_path.parent / str(f)).resolve()) for role, f in (base.get("zenoh") or {}).items()}
    return _merged(base, raw)


def _merged(base: Any, over: Any) -> Any:
    if isinstance(base, dict) and isinstance(over, dict):
        return {**base, **{k: _merged(base[k], v) if k in base else v for k, v in over.items()}}
    return over


def load_spec(path: str | Path, variables: dict[str, str] | None = None, strict: bool = True) -> LaunchSpec:
    """Read a spec and fill its placeholders; ``strict`` refuses placeholders left unfilled."""
    p = Path(path)
    raw = _extended(_read_mapping(p), p)
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
        zenoh_files = {str(role): (p.parent / str(f)).resolve() for role, f in (raw.get("zenoh") or {}).items()}
        return LaunchSpec(
            name=str(raw.get("name", p.stem)),
            vehicle=str(raw.get("vehicle", "ego")),
            router_host=str(router.get("host", "")),
            router_listen=str(router.get("listen", "")),
            hosts={str(k): dict(v or {}) for k, v in (raw.get("hosts") or {}).items()},
            services=services,
            path=p,
            zenoh=zenoh_files,
            unfilled=missing,
        )
    except (KeyError, TypeError, AttributeError) as exc:
        raise ConfigError(f"{p}: malformed service or router entry ({type(exc).__name__}: {exc})") from None


def _schema_ok(schema_id: str) -> type[Message] | None:
    m = re.fullmatch(r"stereovox\.([A-Za-z]+)/(\d+)", schema_id)
    if not m or m.group(1) not in SCHEMAS:
        return None
    cls = SCHEMAS[m.group(1)]
    return cls if int(m.group(2)) == cls.VERSION else None


def _address(spec: LaunchSpec, host: str) -> str:
    return str(spec.hosts.get(host, {}).get("address", ""))


def _check_hosts(spec: LaunchSpec) -> list[str]:
    """Every host has an address; the router listens on its own host's address (or all of them)."""
    errors: list[str] = []
    for role, path in spec.zenoh.items():
        if role not in ZENOH_ROLES:
            errors.append(f"zenoh: role {role!r} is not one of {ZENOH_ROLES}")
        elif not path.is_file():
            errors.append(f"zenoh: {role} configuration {path} does not exist")
    for name, host in spec.hosts.items():
        address = str(host.get("address", "")).strip()
        if not address:
            errors.append(f"host {name}: no address")
            continue
        if _PLACEHOLDER.search(address):
            continue  # --check without --var: the value is not known yet
        try:
            ipaddress.ip_address(address)
        except ValueError:
            if not re.fullmatch(r"[A-Za-z0-9.-]+", address):
                errors.append(f"host {name}: address {address!r} is neither an IP address nor a host name")
    if not spec.router_listen:
        return [*errors, "router: no listen endpoint"]
    if spec.router_host not in spec.hosts:
        return [*errors, f"router: host {spec.router_host!r} is not among hosts {sorted(spec.hosts)}"]
    own = _address(spec, spec.router_host)
    if _PLACEHOLDER.search(spec.router_listen + own):
        return errors
    try:
        listen_host, _ = endpoint_address(spec.router_listen)
    except ConfigError as exc:
        return [*errors, f"router: {exc}"]
    if listen_host not in (own, *WILDCARD_HOSTS):
        errors.append(
            f"router: listens on {listen_host} but its host {spec.router_host} has address {own!r}; "
            "clients on other hosts could not reach it"
        )
    elif listen_host.startswith("127.") or listen_host == "::1":
        remote = sorted({s.host for s in spec.services.values() if _address(spec, s.host) not in ("", own)})
        if remote:
            errors.append(f"router: listens on loopback {listen_host}, out of reach of hosts {remote}")
    return errors


def _check_service(svc: ServiceSpec, spec: LaunchSpec) -> list[str]:
    errors: list[str] = []
    if svc.host not in spec.hosts:
        errors.append(f"service {svc.name}: host {svc.host!r} is not among hosts {sorted(spec.hosts)}")
    if svc.restart not in RESTART_POLICIES:
        errors.append(f"service {svc.name}: restart {svc.restart!r} is not one of {RESTART_POLICIES}")
    if not svc.command:
        return [*errors, f"service {svc.name}: empty command"]
    for key, schema in svc.outputs.items():
        if _schema_ok(schema) is None:
            errors.append(f"service {svc.name}: output {key} has unknown schema or version {schema!r}")
    for key, opts in svc.inputs.items():
        queue = opts.get("queue", "newest")
        if queue not in QUEUE_POLICIES:
            errors.append(f"service {svc.name}: input {key} queue {queue!r} is not one of {QUEUE_POLICIES}")
    if svc.command[0] == "run" and svc.inputs:
        policy = svc.queue_policy()
        given = svc.command[svc.command.index("--policy") + 1] if "--policy" in svc.command[:-1] else None
        if policy is None:
            errors.append(f"service {svc.name}: inputs mix queue policies; stereovox run takes one")
        elif given is not None and given != policy:
            errors.append(f"service {svc.name}: command says --policy {given} but its inputs say {policy}")
    return errors


def _check_code(svc: ServiceSpec) -> list[str]:
    """A ``stereovox run`` stage reads and writes what its code does, not only what the spec says."""
    import importlib

    from common.config_loading import load_config
    from services.runner import SERVICES

    name = svc.command[1] if len(svc.command) > 1 else ""
    if name not in SERVICES:
        return [f"service {svc.name}: stereovox run has no stage {name!r} (one of {sorted(SERVICES)})"]
    # what a stage reads can depend on its settings (the odometry reads vehicle/motion when fusing)
    sets = [svc.command[i + 1] for i, arg in enumerate(svc.command[:-1]) if arg == "--set"]
    try:
        cfg = load_config(None, sets)
    except StereovoxError as exc:
        return [f"service {svc.name}: {exc}"]
    stage = importlib.import_module(SERVICES[name]).stage(cfg)
    errors = [f"service {svc.name}: the code reads {key}, the spec does not list it" for key in stage.inputs
              if key not in svc.inputs]
    errors += [f"service {svc.name}: input {key} is not read by stage {name}" for key in svc.inputs
               if key not in stage.inputs]
    for key, kind in stage.inputs.items():
        want = svc.inputs.get(key, {}).get("schema")
        if want and want != f"stereovox.{kind.SCHEMA}/{kind.VERSION}":
            errors.append(f"service {svc.name}: input {key} says {want}, stage {name} reads "
                          f"stereovox.{kind.SCHEMA}/{kind.VERSION}")
    errors += [f"service {svc.name}: output {key} is not written by stage {name}" for key in svc.outputs
               if key not in stage.outputs]
    errors += [f"service {svc.name}: the code writes {key}, the spec does not list it" for key in stage.outputs
               if key not in svc.outputs]
    return errors


def check(spec: LaunchSpec) -> list[str]:
    """Every problem that would stop the graph from working; empty when it is consistent."""
    errors = _check_hosts(spec)
    publishers: dict[str, list[tuple[str, str]]] = {}
    for svc in spec.services.values():
        errors += _check_service(svc, spec)
        if svc.command[:1] == ["run"]:
            errors += _check_code(svc)
        for key, schema in svc.outputs.items():
            publishers.setdefault(key, []).append((svc.name, schema))
    for key, pubs in publishers.items():
        if len(pubs) > 1:
            errors.append(f"key {key}: published by {len(pubs)} services {[p[0] for p in pubs]}")
    for svc in spec.services.values():
        for key, opts in svc.inputs.items():
            if "*" in key:
                continue  # a wildcard subscriber (the recorder) takes whatever is there
            want = opts.get("schema")
            pubs = publishers.get(key, [])
            if not want:
                errors.append(f"service {svc.name}: input {key} names no schema")
            elif _schema_ok(want) is None:
                errors.append(f"service {svc.name}: input {key} expects unknown schema or version {want!r}")
            if not pubs:
                errors.append(f"service {svc.name}: input {key} has no publisher")
            elif len(pubs) == 1 and want and want != pubs[0][1]:
                errors.append(f"service {svc.name}: input {key} expects {want} but {pubs[0][0]} publishes {pubs[0][1]}")
    return errors
