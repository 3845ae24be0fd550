"""Placing an application's subsystems on hosts: the file's checks, and what each host's runner makes.

The checks run in this process; the runner is only asked what it would hand its subsystems (its
links' keys and endpoints, which subsystems it starts): nothing is started.
"""

from __future__ import annotations

import subprocess

import pytest

from pbo_runtime.config.application import DEFAULT_LINK_PORT, check_application
from pbo_runtime.supervisor.application_runner import ApplicationRunner
from tests.support import PBO, REPO

PLACED = {
    "hosts": "hosts: {arm-a: 10.0.0.1, arm-b: 10.0.0.2}\n",
    "leader": "  leader: {config: leader.yaml, host: arm-a}\n",
    "follower": "  follower: {config: follower.yaml, host: arm-b}\n",
    "operator_host": "    host: arm-a\n",
    "arm_state": "  arm_state: {type: float64, shape: [6], transport: zenoh}\n",
    "goal": "  goal: {kind: message, type: float64, shape: [6], capacity: 4, transport: shm}\n",
}


def write_placed_app(folder, **changes: str) -> str:
    """configs/leader_follower.yaml placed on two hosts (leader and operator on arm-a, the follower on arm-b),
    with `changes` to its parts (see PLACED)."""
    parts = {**PLACED, **changes}
    for name in ("leader.yaml", "follower.yaml"):
        (folder / name).write_text((REPO / "configs" / name).read_text())
    text = (REPO / "configs" / "leader_follower.yaml").read_text()
    operator = text[text.index("  operator:"):text.index("links:\n")]
    operator = operator.replace("  operator:", "  operator:\n" + parts["operator_host"].rstrip("\n"), 1) \
        if parts["operator_host"] else operator
    operator = operator.replace("\n\n", "\n")
    path = folder / "app.yaml"
    path.write_text("application: placed\n" + parts["hosts"] + "subsystems:\n" + parts["leader"] + parts["follower"]
                    + operator + "links:\n" + parts["arm_state"] + parts["goal"] + "run:\n  operator: {app: tour}\n")
    return str(path)


def codes(result) -> list[str]:
    return [e.code for e in result.errors]


def test_a_placed_application_checks_clean_and_knows_each_subsystems_host(tmp_path):
    result = check_application(write_placed_app(tmp_path))
    assert result.ok, [str(e) for e in result.errors]
    app = result.application
    assert app.placement == {"leader": "arm-a", "follower": "arm-b", "operator": "arm-a"}
    assert app.hosts == {"arm-a": "10.0.0.1", "arm-b": "10.0.0.2"}
    assert app.on_host("arm-a") == ["leader", "operator"]
    assert app.links["arm_state"].port == DEFAULT_LINK_PORT  # the first zenoh link of the file


def test_an_inline_subsystem_placed_on_a_host_loads_without_its_host_key(tmp_path):
    result = check_application(write_placed_app(tmp_path))
    assert result.application.subsystems["operator"].name == "operator"
    assert not any("host" in str(w) for w in result.warnings)


def test_the_shipped_application_without_hosts_checks_as_before():
    result = check_application(REPO / "configs" / "leader_follower.yaml")
    assert result.ok and result.application.placement == {} and result.application.hosts == {}


@pytest.mark.parametrize("change, code, wanted", [
    ({"arm_state": "  arm_state: {type: float64, shape: [6], transport: shm}\n"}, "E811",
     "link 'arm_state' joins leader on host 'arm-a' and follower on host 'arm-b', but its transport is shm"),
    ({"follower": "  follower: {config: follower.yaml, host: arm-c}\n"}, "E810",
     "subsystem 'follower' is placed on host 'arm-c', which hosts: does not declare"),
    ({"hosts": "hosts: {arm-a: 10.0.0.1, arm-b: ~}\n"}, "E810", "host 'arm-b' of subsystem 'follower' has no address"),
    ({"follower": "  follower: follower.yaml\n"}, "E810",
     "subsystem 'follower' names no host, while 'leader' is placed on 'arm-a'"),
    ({"hosts": "hosts: {arm-a: 10.0.0.1, arm-b: 'not an address'}\n"}, "E809", "host 'arm-b': address must be"),
    ({"hosts": "hosts: [arm-a, arm-b]\n"}, "E809", "hosts must map each host's name to its address"),
    ({"leader": "  leader: {config: leader.yaml, host: arm-a, cpu: 1}\n"}, "E802", "subsystem 'leader': unknown key 'cpu'"),
    ({"arm_state": "  arm_state: {type: float64, shape: [6], transport: zenoh, port: 70000}\n"}, "E812",
     "link 'arm_state': port must be a TCP port from 1 to 65535"),
    ({"goal": "  goal: {kind: message, type: float64, shape: [6], capacity: 4, transport: shm, port: 7500}\n"}, "E812",
     "link 'goal' takes no port: its transport is shm"),
    ({"arm_state": '  arm_state: {type: float64, shape: [6], transport: zenoh, port: 7500, endpoint: "tcp/10.0.0.1:7447"}\n'},
     "E812", "link 'arm_state' takes no port: its endpoint names one"),
    ({"goal": "  goal: {kind: message, type: float64, shape: [6], capacity: 4, transport: zenoh, port: 7447}\n"}, "E812",
     "links 'arm_state' and 'goal' would both listen on host 'arm-a' at port 7447"),
])
def test_a_placement_mistake_is_reported_at_its_place_with_a_code_and_a_hint(tmp_path, change, code, wanted):
    result = check_application(write_placed_app(tmp_path, **change))
    assert codes(result) == [code], [str(e) for e in result.errors]
    error = result.errors[0]
    assert wanted in error.message and error.hint
    assert error.file.endswith("app.yaml") and error.line > 1


def test_an_unknown_host_gets_the_closest_one_as_a_hint(tmp_path):
    result = check_application(write_placed_app(tmp_path, follower="  follower: {config: follower.yaml, host: arm-bb}\n"))
    assert "did you mean 'arm-b'?" in result.errors[0].hint


def test_an_address_given_on_the_command_line_fills_in_or_overrides_the_files(tmp_path):
    path = write_placed_app(tmp_path, hosts="hosts: {arm-a: 10.0.0.1, arm-b: ~}\n")
    result = check_application(path, {"arm-b": "10.0.0.9", "arm-a": "arm-a.lab"})
    assert result.ok and result.application.hosts == {"arm-a": "arm-a.lab", "arm-b": "10.0.0.9"}


@pytest.mark.parametrize("addresses, wanted", [
    ({"arm-c": "10.0.0.3"}, "--address names host 'arm-c', which the application does not declare"),
    ({"arm-b": "10.0.0.2/24"}, "--address arm-b=10.0.0.2/24: the address must be a host name or an IPv4 address"),
])
def test_a_wrong_address_on_the_command_line_is_refused(tmp_path, addresses, wanted):
    result = check_application(write_placed_app(tmp_path), addresses)
    assert codes(result) == ["E809"] and wanted in result.errors[0].message


def runner(path: str, host: str | None) -> ApplicationRunner:
    result = check_application(path)
    assert result.ok, [str(e) for e in result.errors]
    return ApplicationRunner(result.application, 1.0, lambda text: None, host=host)


@pytest.mark.parametrize("host, subsystems", [
    ("arm-a", ["leader", "operator"]),
    ("arm-b", ["follower"]),
    (None, ["leader", "follower", "operator"]),
])
def test_a_hosts_runner_starts_only_that_hosts_subsystems(tmp_path, host, subsystems):
    assert runner(write_placed_app(tmp_path), host).local == subsystems


def test_both_hosts_derive_the_same_key_and_endpoint_from_the_file_alone(tmp_path):
    path = write_placed_app(tmp_path)
    on_a, on_b = runner(path, "arm-a"), runner(path, "arm-b")
    assert on_a.endpoint("arm_state") == on_b.endpoint("arm_state") == f"tcp/10.0.0.1:{DEFAULT_LINK_PORT}"
    assert runner(path, "arm-a").run_id != runner(path, "arm-a").run_id  # keys never depend on the run


def test_without_a_host_every_zenoh_link_listens_on_loopback_at_its_port_if_written(tmp_path):
    path = write_placed_app(tmp_path, arm_state="  arm_state: {type: float64, shape: [6], transport: zenoh, port: 7601}\n")
    assert runner(path, None).endpoint("arm_state") == "tcp/127.0.0.1:7601"


def test_a_link_endpoint_in_the_file_wins_over_the_hosts_address(tmp_path):
    path = write_placed_app(tmp_path, arm_state='  arm_state: {type: float64, shape: [6], transport: zenoh, '
                                                'endpoint: "tcp/192.168.7.7:9000"}\n')
    assert runner(path, "arm-b").endpoint("arm_state") == "tcp/192.168.7.7:9000"


@pytest.mark.multiprocess
@pytest.mark.parametrize("arguments, wanted", [
    (["--host", "arm-bb"], "--host arm-bb: application 'placed' has no such host; did you mean 'arm-b'?"),
    (["--host", "arm-a", "--address", "arm-a"], "--address takes HOST=ADDRESS"),
    (["--host", "arm-b", "--address", "arm-z=10.0.0.3"], "--address names host 'arm-z'"),
    (["--host", "arm-b"], "is a subsystem file: run it without them"),
])
def test_pbo_run_refuses_a_wrong_host_or_address_in_one_line(tmp_path, arguments, wanted):
    app = write_placed_app(tmp_path)
    file = str(tmp_path / "follower.yaml") if "subsystem file" in wanted else app
    done = subprocess.run([*PBO, "run", file, *arguments, "--duration", "0.1"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 1, done.stdout + done.stderr
    assert wanted in " ".join(done.stderr.split()) and "Traceback" not in done.stderr


@pytest.mark.multiprocess
def test_pbo_check_takes_an_address_and_says_where_each_subsystem_runs(tmp_path):
    path = write_placed_app(tmp_path, hosts="hosts: {arm-a: 10.0.0.1, arm-b: ~}\n")
    missing = subprocess.run([*PBO, "check", path], capture_output=True, text=True, timeout=120)
    assert missing.returncode == 1 and "E810" in missing.stderr
    given = subprocess.run([*PBO, "check", path, "--address", "arm-b=10.0.0.2"], capture_output=True, text=True, timeout=120)
    assert given.returncode == 0, given.stderr
    said = " ".join(given.stdout.split())  # lines may wrap
    assert "subsystem follower: " in said and "on arm-b (10.0.0.2)" in said
