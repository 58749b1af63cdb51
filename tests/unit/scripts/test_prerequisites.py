"""``./run test`` sets up what the suite needs from the system (``scripts/test_prerequisites.sh``), and
``.ci/run`` only calls it.

The script runs here against a fake system: a PATH of stand-ins for ``id``, ``apt-get``, ``sudo``,
``ldconfig``, ``node`` and ``npm`` that record how they were called, a fake interpreter that has
``pyrealsense2`` or not, and ``EIGENSCOPE_TEST_CHROMIUM`` for the browser (the variable the browser tests
read).
"""

from __future__ import annotations

import os
import shlex
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
SCRIPT = ROOT / "scripts" / "test_prerequisites.sh"
#: Real tools the script may use besides the faked ones.
REAL_TOOLS = ("bash", "env", "grep", "mktemp", "rm", "tail", "cat", "printf", "true")
LIBUSB_LINE = "\tlibusb-1.0.so.0 (libc6,x86-64) => /lib/x86_64-linux-gnu/libusb-1.0.so.0"


class FakeSystem:
    """What the script sees: which user it runs as, what is installed, and whether apt-get works."""

    def __init__(self, root: Path) -> None:
        self.bin = root / "bin"
        self.bin.mkdir()
        self.calls = root / "calls"
        self.root = root
        for tool in REAL_TOOLS:
            real = subprocess.run(["bash", "-c", f"type -P {tool}"], capture_output=True, text=True)
            if real.returncode == 0 and real.stdout.startswith("/"):
                (self.bin / tool).symlink_to(real.stdout.strip())
        self.chromium = root / "chromium"
        self.python = root / "python"
        self.user(0)
        self.libusb(installed=True)
        self.pyrealsense2(installed=True)
        self.tool("node")
        self.tool("npm")
        self.chromium.write_text("")
        self.apt(status=0)

    def _stub(self, name: str, body: str) -> None:
        path = self.bin / name
        path.write_text(f"#!/bin/bash\n{body}\n")
        path.chmod(0o755)

    def tool(self, name: str) -> None:
        self._stub(name, "exit 0")

    def remove(self, name: str) -> None:
        (self.bin / name).unlink(missing_ok=True)

    def user(self, uid: int, *, sudo: bool = False) -> None:
        self._stub("id", f"echo {uid}")
        if sudo:  # sudo -n CMD runs CMD (no password needed)
            self._stub("sudo", f'echo "sudo $*" >> {self.calls}; [ "$1" = -n ] && shift; exec "$@"')
        else:
            self._stub("sudo", "echo 'sudo: a password is required' >&2; exit 1")

    def libusb(self, *, installed: bool) -> None:
        self._stub("ldconfig", f"printf '%s\\n' {shlex.quote(LIBUSB_LINE)}" if installed else "exit 0")

    def pyrealsense2(self, *, installed: bool) -> None:
        self.python.write_text(f"#!/bin/bash\nexit {0 if installed else 1}\n")
        self.python.chmod(0o755)

    def apt(self, *, status: int) -> None:
        """apt-get records its arguments and whether its stdin was at its end (never a terminal)."""
        self._stub(
            "apt-get",
            f'stdin=open; read -r -t 1 _ || stdin=eof; echo "apt-get $* DEBIAN_FRONTEND=$DEBIAN_FRONTEND'
            f' stdin=$stdin" >> {self.calls}; echo "E: apt failed here" >&2; [ "$1" = update ] && exit 0;'
            f" exit {status}",
        )

    def run(self, *, ci: bool = False) -> subprocess.CompletedProcess[str]:
        env = {"PATH": str(self.bin), "HOME": str(self.root), "EIGENSCOPE_TEST_CHROMIUM": str(self.chromium)}
        if ci:
            env["CI"] = "true"
        return subprocess.run(
            [str(self.bin / "bash"), str(SCRIPT), str(self.python)],
            capture_output=True,
            text=True,
            env=env,
            timeout=60,
            check=False,
            stdin=subprocess.DEVNULL,
        )

    def apt_calls(self) -> list[str]:
        return self.calls.read_text().splitlines() if self.calls.exists() else []


@pytest.fixture
def system(tmp_path: Path) -> FakeSystem:
    return FakeSystem(tmp_path)


def test_silent_and_untouched_when_everything_is_there(system: FakeSystem) -> None:
    done = system.run(ci=True)
    assert (done.returncode, done.stdout, done.stderr) == (0, "", "")
    assert system.apt_calls() == []


def test_libusb_is_needed_only_where_pyrealsense2_is_installed(system: FakeSystem) -> None:
    system.libusb(installed=False)
    system.pyrealsense2(installed=False)
    done = system.run(ci=True)
    assert (done.returncode, done.stdout, done.stderr) == (0, "", "")


def test_root_installs_what_is_missing_with_apt_in_one_go_without_stdin(system: FakeSystem) -> None:
    system.chromium.unlink()
    system.libusb(installed=False)
    system.remove("npm")  # node is there: npm alone is installed
    done = system.run(ci=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout == "== installing chromium libusb-1.0-0 npm (apt-get) for the tests\n"
    assert done.stderr == ""  # apt's output is kept unless it fails
    assert system.apt_calls() == [
        "apt-get update -qq DEBIAN_FRONTEND=noninteractive stdin=eof",
        "apt-get install -y -qq chromium libusb-1.0-0 npm DEBIAN_FRONTEND=noninteractive stdin=eof",
    ]


def test_node_and_npm_together_when_neither_is_there(system: FakeSystem) -> None:
    system.remove("node")
    system.remove("npm")
    done = system.run()
    assert done.returncode == 0, done.stderr
    assert system.apt_calls()[-1].startswith("apt-get install -y -qq nodejs npm ")


def test_a_user_with_passwordless_sudo_installs_through_it(system: FakeSystem) -> None:
    system.user(1000, sudo=True)
    system.chromium.unlink()
    done = system.run(ci=True)
    assert done.returncode == 0, done.stderr
    assert "sudo -n env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium" in system.apt_calls()


@pytest.mark.parametrize("ci", [False, True], ids=["local", "ci"])
def test_a_user_without_sudo_is_told_what_is_missing_and_how_to_get_it(system: FakeSystem, ci: bool) -> None:
    system.user(1000)
    system.chromium.unlink()
    system.libusb(installed=False)
    done = system.run(ci=ci)
    assert system.apt_calls() == []
    lines = done.stderr.splitlines()
    assert lines[0] == (
        "missing for the tests: chromium (the browser tests), "
        "libusb-1.0-0 (pyrealsense2, the RealSense tests)"
    )
    assert lines[1] == "install with: sudo apt-get install -y chromium libusb-1.0-0"
    # Locally the tests that need them skip, naming what they miss; CI must not go on without them.
    assert done.returncode == (1 if ci else 0), done.stderr


def test_a_failed_install_shows_apt_and_what_to_do(system: FakeSystem) -> None:
    system.chromium.unlink()
    system.apt(status=100)
    done = system.run(ci=True)
    assert done.returncode == 1
    assert "E: apt failed here" in done.stderr
    assert "test_prerequisites: apt-get could not install chromium" in done.stderr
    assert "install with: sudo apt-get install -y chromium" in done.stderr


def test_run_test_sets_the_system_up_and_ci_only_calls_it() -> None:
    run = (ROOT / "run").read_text()
    test_branch = run.split("\n    test)\n", 1)[1].split(";;", 1)[0]
    steps = [
        line.strip() for line in test_branch.splitlines() if line.strip() and not line.strip().startswith("#")
    ]
    assert steps[:2] == ["ensure_venv", 'bash scripts/test_prerequisites.sh "$VENV/bin/python"']
    ci = (ROOT / ".ci" / "run").read_text()
    commands = [line for line in ci.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    assert commands == ["set -euo pipefail", 'cd "$(dirname "$0")/.."', "exec ./run test"]
    assert os.access(ROOT / ".ci" / "run", os.X_OK)
