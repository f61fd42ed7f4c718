"""scripts/services.sh (run by scripts/test.sh before the suite) fails loudly, with the
cause, whenever PostgreSQL or Redis cannot be installed, started or reached — never exit 0
after "did not come up", never a start error masked, never success because a client tool
is absent. Each case runs the script on a PATH of stubs (the real servers are not touched:
every server command the script may call is a stub here)."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "services.sh"
SERVER_TOOLS = ("pg_isready", "pg_ctlcluster", "psql", "redis-server", "redis-cli",
                "apt-get", "sudo")


def _bin(tmp: Path, stubs: dict[str, str]) -> Path:
    """A bin folder with every ordinary command of this machine except the server tools,
    plus ``stubs`` (name → shell body)."""
    b = tmp / "bin"
    b.mkdir()
    for d in os.environ["PATH"].split(os.pathsep):
        if not os.path.isdir(d):
            continue
        for name in os.listdir(d):
            target = b / name
            if name in SERVER_TOOLS or target.exists() or target.is_symlink():
                continue
            src = os.path.join(d, name)
            if os.access(src, os.X_OK) and not os.path.isdir(src):
                target.symlink_to(src)
    for name, body in stubs.items():
        (b / name).write_text(f"#!/bin/sh\n{body}\n")
        (b / name).chmod(0o755)
    return b


def _run(tmp: Path, stubs: dict[str, str]) -> subprocess.CompletedProcess:
    conf = tmp / "pgconf" / "15" / "main"
    conf.mkdir(parents=True)
    (conf / "pg_hba.conf").write_text("host all all 127.0.0.1/32 trust\n")
    env = {"PATH": str(_bin(tmp, stubs)), "HOME": str(tmp),
           "PRT_SERVICES_PG_CONF": str(tmp / "pgconf"), "PRT_SERVICES_WAIT_S": "1",
           "PRT_SERVICES_LOG_DIR": str(tmp / "logs")}
    return subprocess.run(["bash", str(SCRIPT)], env=env, capture_output=True, text=True,
                          timeout=60)


UP = {"pg_isready": "exit 0", "pg_ctlcluster": "exit 0", "psql": "echo 1",
      "redis-server": "exit 0", "redis-cli": "echo PONG"}
APT_FAILS = {"apt-get": "echo 'E: Unable to locate package' >&2; exit 100",
             "sudo": 'shift; exec "$@"'}  # when not root: sudo -n CMD runs CMD


@pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash")
@pytest.mark.parametrize(("case", "stubs", "cause"), [
    ("all up", UP, None),
    ("pg_isready absent, install fails",
     {**{k: v for k, v in UP.items() if k != "pg_isready"}, **APT_FAILS},
     "apt-get update failed"),
    ("redis-cli absent, no apt-get",
     {k: v for k, v in UP.items() if k != "redis-cli"},
     "apt-get is not available"),
    ("psql absent, install fails", {**{k: v for k, v in UP.items() if k != "psql"},
                                    **APT_FAILS}, "apt-get update failed"),
    ("postgres start fails", {**UP, "pg_isready": "exit 2",
                              "pg_ctlcluster": "echo 'could not bind' >&2; exit 1"},
     "pg_ctlcluster 15 main start failed"),
    ("postgres never comes up", {**UP, "pg_isready": "exit 2"},
     "PostgreSQL did not come up within 1 s"),
    ("redis start fails", {**UP, "redis-cli": "exit 1",
                           "redis-server": "echo 'Address in use' >&2; exit 1"},
     "redis-server failed to start"),
    ("redis never comes up", {**UP, "redis-cli": "exit 1"}, "Redis did not come up"),
    ("postgres refuses the test role", {**UP, "psql": "echo 'password required' >&2; exit 2"},
     "cannot connect without a password"),
], ids=lambda x: x if isinstance(x, str) and " " in x else "")
def test_services_script_fails_loudly_with_the_cause(tmp_path, case, stubs, cause):
    r = _run(tmp_path, stubs)
    if cause is None:
        assert r.returncode == 0, r.stderr
        return
    assert r.returncode == 1, (case, r.returncode, r.stderr)
    assert cause in r.stderr, (case, r.stderr)
